"""The paper's Table 1 (reaching static and moving targets) measured on held-out tasks.

For every speed row, the policy and the IK-interpolation baseline run on the same evaluation
tasks (same seeds, so the same start, target and target motion). Reported per row:
- success rate (tip within 2 cm, no collision),
- path length ratio: the policy's tip path divided by the baseline's on the same task, averaged
  over tasks both solved (the paper's "Avg Path Length", normalised by the near-optimal path),
- inference time: median wall time of one `act` call at batch 1, milliseconds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from clamgen.baselines import IKInterpolationPolicy
from clamgen.envs import ReachEnv
from clamgen.experiments.config import EVAL_SEED_BASE
from clamgen.experiments.evaluate import EpisodeRecord, evaluate
from clamgen.policy import Policy

TABLE1_SPEEDS: tuple[float | str, ...] = (0.0, 0.05, 0.1, 0.2, "variable")
# The paper's Table 1 (joint policy and 2-view image policy): success and path length ratio.
PAPER_TABLE1 = {
    "joints": {
        0.05: (1.0, 0.90175),
        0.1: (1.0, 0.913),
        0.2: (1.0, 1.062),
        "variable": (1.0, 0.9048),
    },
    "images": {0.05: (1.0, 1.012), 0.1: (1.0, 1.16), 0.2: (1.0, 1.20), "variable": (1.0, 1.09)},
}
PAPER_INFERENCE_MS = {"joints": 0.4216, "images": 4.906}


@dataclass
class SpeedRow:
    speed: float | str
    num_tasks: int
    success_rate: float
    baseline_success_rate: float
    path_ratio: float
    path_ratio_tasks: int
    median_act_ms: float
    mean_steps: float

    def label(self) -> str:
        return "variable [5-20]" if self.speed == "variable" else f"{100 * self.speed:g}"


def path_ratio(policy: list[EpisodeRecord], baseline: list[EpisodeRecord]) -> tuple[float, int]:
    """Mean per-task tip-path ratio over tasks both solved, and how many tasks that is."""
    ratios = [
        p.tip_path_m / b.tip_path_m
        for p, b in zip(policy, baseline, strict=True)
        if p.success and b.success and b.tip_path_m > 0
    ]
    return (float(np.mean(ratios)) if ratios else float("nan")), len(ratios)


def table1(
    policy: Policy,
    num_tasks: int = 200,
    speeds=TABLE1_SPEEDS,
    env_kwargs: dict[str, Any] | None = None,
    progress=None,
) -> list[SpeedRow]:
    """Evaluate `policy` and the IK baseline on `num_tasks` held-out tasks per speed."""
    env_kwargs = env_kwargs or {}
    rows = []
    seeds = EVAL_SEED_BASE + np.arange(num_tasks)
    for speed in speeds:
        env = ReachEnv(num_obstacles=0, target_speed=speed, **env_kwargs)
        # The baseline needs joints and the goal, whatever the policy observes.
        baseline_env = ReachEnv(num_obstacles=0, target_speed=speed)
        records = evaluate(env, policy, seeds)
        baseline = evaluate(baseline_env, IKInterpolationPolicy(), seeds)
        ratio, count = path_ratio(records, baseline)
        act_ms = np.median(np.concatenate([r.act_times_s for r in records])) * 1e3
        rows.append(
            SpeedRow(
                speed=speed,
                num_tasks=num_tasks,
                success_rate=float(np.mean([r.success for r in records])),
                baseline_success_rate=float(np.mean([r.success for r in baseline])),
                path_ratio=ratio,
                path_ratio_tasks=count,
                median_act_ms=float(act_ms),
                mean_steps=float(np.mean([r.steps for r in records])),
            )
        )
        if progress is not None:
            progress(rows[-1])
        env.close()
    return rows


def table1_markdown(rows: list[SpeedRow], observation: str = "joints") -> str:
    """Markdown: our numbers beside the paper's."""
    paper = PAPER_TABLE1[observation]
    lines = [
        f"| {observation} policy, speed (cm/s) | success | paper | path ratio | paper "
        "| IK baseline success | inference (ms, median) | paper (ms) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        paper_success, paper_ratio = paper.get(row.speed, (None, None))
        fmt = lambda v, spec=".3f": "-" if v is None else format(v, spec)  # noqa: E731
        lines.append(
            f"| {row.label()} | {row.success_rate:.3f} | {fmt(paper_success, '.2f')} "
            f"| {row.path_ratio:.3f} | {fmt(paper_ratio)} | {row.baseline_success_rate:.3f} "
            f"| {row.median_act_ms:.4f} | {PAPER_INFERENCE_MS[observation]} |"
        )
    return "\n".join(lines)


def write_table1(rows: list[SpeedRow], out: Path, meta: dict[str, Any]) -> None:
    """`out`.json (rows + how they were made) and `out`.md."""
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {**meta, "rows": [row.__dict__ for row in rows]}
    out.with_suffix(".json").write_text(json.dumps(data, indent=2))
    observation = meta.get("observation", "joints")
    out.with_suffix(".md").write_text(table1_markdown(rows, observation) + "\n")


__all__ = ["TABLE1_SPEEDS", "SpeedRow", "table1", "table1_markdown", "write_table1"]
