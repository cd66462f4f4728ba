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
    step_ratio: float = float("nan")
    """Steps to the target divided by the baseline's on the same task (time, not distance),
    averaged over tasks both solved."""

    def label(self) -> str:
        return "variable [5-20]" if self.speed == "variable" else f"{100 * self.speed:g}"


def path_ratio(
    policy: list[EpisodeRecord], baseline: list[EpisodeRecord], attribute: str = "tip_path_m"
) -> tuple[float, int]:
    """Mean per-task ratio of `attribute` (tip path by default) over tasks both solved, and
    how many tasks that is."""
    ratios = [
        getattr(p, attribute) / getattr(b, attribute)
        for p, b in zip(policy, baseline, strict=True)
        if p.success and b.success and getattr(b, attribute) > 0
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
                step_ratio=path_ratio(records, baseline, "steps")[0],
            )
        )
        if progress is not None:
            progress(rows[-1])
        env.close()
    return rows


def table1_markdown(rows: list[SpeedRow], observation: str = "joints") -> str:
    """Markdown: our numbers beside the paper's."""
    paper = PAPER_TABLE1.get(observation, {})
    paper_ms = PAPER_INFERENCE_MS.get(observation, "-")
    lines = [
        f"| {observation} policy, speed (cm/s) | success | paper | path ratio | paper "
        "| steps ratio | IK baseline success | inference (ms, median) | paper (ms) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        paper_success, paper_ratio = paper.get(row.speed, (None, None))
        fmt = lambda v, spec=".3f": "-" if v is None else format(v, spec)  # noqa: E731
        lines.append(
            f"| {row.label()} | {row.success_rate:.3f} | {fmt(paper_success, '.2f')} "
            f"| {row.path_ratio:.3f} | {fmt(paper_ratio)} | {row.step_ratio:.3f} "
            f"| {row.baseline_success_rate:.3f} "
            f"| {row.median_act_ms:.4f} | {paper_ms} |"
        )
    return "\n".join(lines)


def write_table1(rows: list[SpeedRow], out: Path, meta: dict[str, Any]) -> None:
    """`out`.json (rows + how they were made) and `out`.md."""
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {**meta, "rows": [row.__dict__ for row in rows]}
    out.with_suffix(".json").write_text(json.dumps(data, indent=2))
    observation = meta.get("observation", "joints")
    out.with_suffix(".md").write_text(table1_markdown(rows, observation) + "\n")


# ------------------------------------------------------------------------- Table 2
# The paper's Table 2 (static targets, two obstacles): success rate per row.
PAPER_TABLE2 = {
    "CLAMGen, 3 RGBD views": 0.81,
    "CLAMGen, 2 RGBD views": 0.76,
    "CLAMGen, 1 RGBD view": 0.475,
    "no residual (2 views)": 0.30,
    "no HER (2 views)": 0.625,
    "no view dropout (2 views)": 0.565,
    "no collision loss (2 views)": 0.55,
    "vanilla CURL + HER (3 views)": 0.24,
    "RRT with full model": 1.0,
}


@dataclass
class ObstacleRow:
    name: str
    num_tasks: int
    success_rate: float
    collision_rate: float
    reach_rate: float
    mean_tip_path_m: float
    median_act_ms: float
    median_step_ms: float = float("nan")
    plan_time_median_s: float | None = None
    plan_time_p95_s: float | None = None
    task_success: list[bool] | None = None
    """Success per task, in evaluation-seed order (for the blocked-task column)."""


class _PlanTimeRecorder:
    """Wraps a planning policy to collect its per-episode planning time."""

    def __init__(self, policy) -> None:
        self.policy = policy
        self.times: list[float] = []

    def reset(self, env=None) -> None:
        self.policy.reset(env)
        if getattr(self.policy, "last_plan_time_s", None) is not None:
            self.times.append(self.policy.last_plan_time_s)

    def act(self, obs):
        return self.policy.act(obs)


def table2_row(
    name: str, policy: Policy, num_tasks: int = 200, env_kwargs: dict[str, Any] | None = None
) -> ObstacleRow:
    """One Table 2 row: `policy` on `num_tasks` held-out obstacle tasks (static targets).

    For a planner (anything with `last_plan_time_s`) the per-task planning time is reported;
    it is spent in `reset`, before the first action, and is not part of the act time.
    """
    env = ReachEnv(num_obstacles=2, **(env_kwargs or {}))
    recorder = _PlanTimeRecorder(policy)
    records = evaluate(env, recorder, EVAL_SEED_BASE + np.arange(num_tasks))
    env.close()
    times = np.array(recorder.times) if recorder.times else None
    return ObstacleRow(
        name=name,
        num_tasks=num_tasks,
        success_rate=float(np.mean([r.success for r in records])),
        collision_rate=float(np.mean([r.collided for r in records])),
        reach_rate=float(np.mean([r.reached for r in records])),
        mean_tip_path_m=float(np.mean([r.tip_path_m for r in records])),
        median_act_ms=float(np.median(np.concatenate([r.act_times_s for r in records])) * 1e3),
        median_step_ms=float(np.median(np.concatenate([r.step_times_s for r in records])) * 1e3),
        plan_time_median_s=None if times is None else float(np.median(times)),
        plan_time_p95_s=None if times is None else float(np.percentile(times, 95)),
        task_success=[bool(r.success) for r in records],
    )


BLOCKING_ROW = "IK interpolation (no obstacle model)"
"""The row whose failures define the "blocked" tasks: those where moving straight to the goal
(IK interpolation, blind to the obstacles) does not succeed, so an obstacle is in the way."""


def blocked_tasks(rows: list[ObstacleRow]) -> np.ndarray | None:
    """Per-task mask (True = blocked) from the `BLOCKING_ROW`'s failures, or None without its
    per-task results."""
    for row in rows:
        if row.name == BLOCKING_ROW and row.task_success is not None:
            return ~np.asarray(row.task_success, bool)
    return None


def blocked_success(row: ObstacleRow, blocked: np.ndarray) -> float | None:
    """`row`'s success rate on the blocked tasks; None if it has no per-task results for the
    same tasks, or there are no blocked tasks."""
    if row.task_success is None or len(row.task_success) != len(blocked) or not blocked.any():
        return None
    return float(np.asarray(row.task_success, bool)[blocked].mean())


def table2_markdown(rows: list[ObstacleRow]) -> str:
    """Markdown of Table 2 rows. When the IK-interpolation row is among them with per-task
    results, a column gives each row's success on the tasks it failed (obstacle in the way)."""
    blocked = blocked_tasks(rows)
    blocked_header = "" if blocked is None else f" success on blocked tasks (n={blocked.sum()}) |"
    lines = [
        "| row | success | paper |" + blocked_header + " collision rate | reached | tip path (m) "
        "| act (ms, median) | env step incl. rendering (ms) | planning (s, median / p95) |",
        "|---|---|---|---|---|---|---|---|---|" + ("" if blocked is None else "---|"),
    ]
    for row in rows:
        paper = PAPER_TABLE2.get(row.name)
        planning = (
            "-"
            if row.plan_time_median_s is None
            else f"{row.plan_time_median_s:.3f} / {row.plan_time_p95_s:.3f}"
        )
        blocked_cell = ""
        if blocked is not None:
            value = blocked_success(row, blocked)
            blocked_cell = " - |" if value is None else f" {value:.3f} |"
        lines.append(
            f"| {row.name} | {row.success_rate:.3f} | {'-' if paper is None else paper} |"
            f"{blocked_cell} {row.collision_rate:.3f} | {row.reach_rate:.3f} "
            f"| {row.mean_tip_path_m:.3f} | {row.median_act_ms:.4f} "
            f"| {row.median_step_ms:.3f} | {planning} |"
        )
    return "\n".join(lines)
