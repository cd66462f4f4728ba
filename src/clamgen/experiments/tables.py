"""The paper's Tables 1 and 2 measured on held-out tasks (the test seed range).

Every table runs on `TEST_SEEDS` (`clamgen.experiments.config`) and refuses any other seed,
validation seeds included: those are for choices made while training.

Table 1 (reaching static and moving targets).

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
from clamgen.experiments.config import TEST_SEEDS, check_table_seeds
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
# RRT on Table 1: it plans once, open loop, to where the target is at reset, so it reaches static
# targets and misses moving ones by design (the paper runs RRT on static obstacle tasks only).
RRT_TABLE1_NOTE = (
    "RRT plans once, open loop, to the target's position at reset: it is the baseline for static "
    "obstacle tasks (Table 2, `--table 2`); on moving targets its success is 0 by design"
)
DEPTH_RRT_TABLE1_NOTE = (
    "RRT on the depth map plans at the first step to meet the target where its observed "
    "velocity will take it, and again when the target leaves that course or the arm stalls; "
    "planning takes no simulated time (the arm and the target wait for each plan)"
)


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
    first_seed: int = TEST_SEEDS.start,
) -> list[SpeedRow]:
    """Evaluate `policy` and the IK baseline on `num_tasks` held-out tasks per speed, seeds
    `first_seed`, `first_seed` + 1, ... (test seeds only: a ValueError otherwise)."""
    env_kwargs = env_kwargs or {}
    rows = []
    seeds = check_table_seeds(first_seed, num_tasks)
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


def table1_markdown(
    rows: list[SpeedRow], observation: str = "joints", note: str | None = None
) -> str:
    """Markdown: our numbers beside the paper's, and `note` below the table if given."""
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
    if note:
        lines += ["", f"Note: {note}."]
    return "\n".join(lines)


def write_table1(rows: list[SpeedRow], out: Path, meta: dict[str, Any]) -> None:
    """`out`.json (rows + how they were made) and `out`.md."""
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {**meta, "rows": [row.__dict__ for row in rows]}
    out.with_suffix(".json").write_text(json.dumps(data, indent=2))
    observation = meta.get("observation", "joints")
    markdown = table1_markdown(rows, observation, meta.get("note"))
    out.with_suffix(".md").write_text(markdown + "\n")


# ------------------------------------------------------------------------- Table 2
# Task families of Table 2: the paper's obstacle tasks and ours with the blind path blocked
# (`clamgen.tasks.blocked`), both with two obstacles.
TABLE2_FAMILIES = ("obstacles", "blocked")
ACT_AIM_MS = 2.0
"""The blocked-path issue's act time per step on one core (under it); Table 2 rows record the
share of their acts that take longer (`ObstacleRow.act_share_over_aim`)."""
FAMILY_TITLES = {"obstacles": "standard obstacle tasks", "blocked": "blocked-path tasks"}
# The paper's Table 2 (static targets, two obstacles, its own task sampling): success rate per
# row. It stands beside our standard column; the paper has no blocked-path tasks.
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
# Two-sided 95% normal quantile, for the Wilson score interval.
Z_95 = 1.959963984540054


def wilson_interval(successes: int, num_tasks: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval (low, high) of a success rate; 95% by default.

    Unlike the normal approximation it stays inside [0, 1] and is not empty at 0 or n
    successes (Wilson 1927; Brown, Cai & DasGupta 2001 recommend it for n >= 40).
    """
    if num_tasks < 1 or not 0 <= successes <= num_tasks:
        raise ValueError(f"need 0 <= successes <= num_tasks >= 1, got {successes}/{num_tasks}")
    p = successes / num_tasks
    denominator = 1 + z**2 / num_tasks
    centre = (p + z**2 / (2 * num_tasks)) / denominator
    half = z * np.sqrt(p * (1 - p) / num_tasks + z**2 / (4 * num_tasks**2)) / denominator
    # At 0 or n successes one bound is exactly 0 or 1 (rounding would leave ~1e-18).
    low = 0.0 if successes == 0 else float(max(0.0, centre - half))
    high = 1.0 if successes == num_tasks else float(min(1.0, centre + half))
    return low, high


@dataclass(frozen=True)
class PairedCount:
    """Two policies on the same tasks: how many tasks only the first solves (`first_only`),
    only the second (`second_only`), and the exact two-sided sign test's P on those tasks
    (McNemar's exact test; 1.0 when they never disagree)."""

    first_only: int
    second_only: int
    p_value: float


def paired_count(first, second) -> PairedCount:
    """Compare two per-task success lists of the same tasks in the same order."""
    from scipy.stats import binomtest

    a, b = np.asarray(first, dtype=bool), np.asarray(second, dtype=bool)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"need two per-task lists of one length, got {a.shape} and {b.shape}")
    first_only, second_only = int((a & ~b).sum()), int((b & ~a).sum())
    disagree = first_only + second_only
    p = binomtest(first_only, disagree).pvalue if disagree else 1.0
    return PairedCount(first_only, second_only, float(p))


@dataclass
class ObstacleRow:
    """One Table 2 row on one task family. Rates are fractions of `num_tasks`."""

    name: str
    num_tasks: int
    success_rate: float
    """Reached the target with no collision at any step."""
    collision_rate: float
    """Some step collided."""
    reach_rate: float
    """Reached the target, collisions aside."""
    mean_tip_path_m: float
    median_act_ms: float
    median_step_ms: float = float("nan")
    plan_time_median_s: float | None = None
    plan_time_p95_s: float | None = None
    """Planning time per task, for a policy that plans: the RRT baseline before its first
    action, the depth-map planner while acting (its tasks without a plan count 0 s)."""
    act_p99_ms: float | None = None
    act_max_ms: float | None = None
    """The act time's tail over all steps (a planning step of the depth-map planner is one
    act); None in rows measured before they were recorded."""
    act_share_over_aim: float | None = None
    """The share of all acts that took longer than `ACT_AIM_MS`; None in rows measured before
    session 41."""
    task_success: list[bool] | None = None
    """Success per task, in seed order."""
    family: str = "obstacles"
    """Task family: "obstacles" (`CLAMGen/ReachObstacles-v0`) or "blocked"
    (`CLAMGen/ReachBlocked-v0`)."""
    first_seed: int = TEST_SEEDS.start
    """Tasks are seeds first_seed .. first_seed + num_tasks - 1."""
    mean_steps: float | None = None
    """Steps per episode (it ends at the target, or after `MAX_EPISODE_STEPS`): how fast the
    arm gets there; None in rows measured before it was recorded."""
    target_speed: float = 0.0
    """The target's speed, m/s: 0 in the paper's Table 2 (static targets); a moving target
    among the obstacles is beyond the paper (`clamgen eval --table 2 --target-speed`)."""
    task_steps: list[int] | None = None
    task_tip_path_m: list[float] | None = None
    """Steps and the tip's path length (m) per task, in seed order: how fast and how far the
    arm went, to compare rows on the tasks both solve; None in rows measured before session
    43."""
    real_time: bool = False
    """Acting took simulated time (`clamgen eval --table 2 --real-time`, beyond the paper): an
    act longer than the 50 ms control period held the arm still a step for each whole period
    (`evaluate.run_episode`); False, as in the paper, acting takes none."""
    task_held_steps: list[int] | None = None
    """With `real_time`: the steps per task the arm held still while the policy computed."""
    depth_noise_m: float = 0.0
    """The depth images' noise, standard deviation `depth_noise_m * z**2` at depth z (m)
    (`clamgen eval --table 2 --depth-noise-m`, beyond the paper); 0, as in the paper: exact."""
    task_collided: list[bool] | None = None
    """Whether some step collided, per task, in seed order (to compare rows' collisions task
    by task); None in rows measured before session 49."""

    @property
    def num_successes(self) -> int:
        return round(self.success_rate * self.num_tasks)

    @property
    def success_interval(self) -> tuple[float, float]:
        """95% Wilson score interval of the success rate."""
        return wilson_interval(self.num_successes, self.num_tasks)

    @property
    def failure_split(self) -> dict[str, int]:
        """Failed tasks by kind (they add up to all failures), from the three rates:
        collided and never reached / stalled without a collision / reached after a collision
        (an episode ends when the target is reached, so a collision came first)."""
        n = self.num_tasks
        reached_after_collision = round((self.reach_rate - self.success_rate) * n)
        collided_never_reached = round(self.collision_rate * n) - reached_after_collision
        stalled = n - self.num_successes - collided_never_reached - reached_after_collision
        return {
            "collided_never_reached": collided_never_reached,
            "stalled_no_collision": stalled,
            "reached_after_collision": reached_after_collision,
        }


class _PlanTimeRecorder:
    """Wraps a policy to collect its planning time per episode, if it plans: in `reset`
    (`last_plan_time_s`, the RRT baseline) or while acting (`episode_plan_time_s`, read when
    the episode is over: at the next reset or `finish`)."""

    def __init__(self, policy) -> None:
        self.policy = policy
        self.times: list[float] = []
        self._acting = False  # an episode of a policy that plans while acting is under way

    def reset(self, env=None) -> None:
        self._close_episode()
        self.policy.reset(env)
        if getattr(self.policy, "last_plan_time_s", None) is not None:
            self.times.append(self.policy.last_plan_time_s)
        self._acting = hasattr(self.policy, "episode_plan_time_s")

    def act(self, obs):
        return self.policy.act(obs)

    def skipped(self, steps: int) -> None:
        if hasattr(self.policy, "skipped"):
            self.policy.skipped(steps)

    def _close_episode(self) -> None:
        if self._acting:
            self.times.append(float(self.policy.episode_plan_time_s))
            self._acting = False

    def finish(self) -> list[float]:
        """The planning time of every episode run (empty for a policy that does not plan)."""
        self._close_episode()
        return self.times


def table2_row(
    name: str,
    policy: Policy,
    num_tasks: int = 200,
    env_kwargs: dict[str, Any] | None = None,
    family: str = "obstacles",
    first_seed: int = TEST_SEEDS.start,
    real_time: bool = False,
) -> ObstacleRow:
    """One Table 2 row: `policy` on `num_tasks` held-out tasks of `family`, seeds `first_seed`,
    `first_seed` + 1, ... (test seeds only: a ValueError otherwise); static targets unless
    `env_kwargs` has a `target_speed`; with `real_time`, acting takes simulated time
    (`evaluate.run_episode`).

    For a planner the per-task planning time is reported: for one with `last_plan_time_s`
    (the RRT baseline) it is spent in `reset`, before the first action, and is not part of the
    act time; for one with `episode_plan_time_s` (the depth-map planner) it is spent in the
    acts that plan, and is part of their act time.
    """
    if family not in TABLE2_FAMILIES:
        raise ValueError(f"family must be one of {TABLE2_FAMILIES}, got {family!r}")
    seeds = check_table_seeds(first_seed, num_tasks)
    env = ReachEnv(num_obstacles=2, task_family=family, **(env_kwargs or {}))
    recorder = _PlanTimeRecorder(policy)
    records = evaluate(env, recorder, seeds, real_time)
    env.close()
    times = recorder.finish()
    times = np.array(times) if times else None
    act_ms = np.concatenate([r.act_times_s for r in records]) * 1e3
    return ObstacleRow(
        name=name,
        num_tasks=num_tasks,
        success_rate=float(np.mean([r.success for r in records])),
        collision_rate=float(np.mean([r.collided for r in records])),
        reach_rate=float(np.mean([r.reached for r in records])),
        mean_tip_path_m=float(np.mean([r.tip_path_m for r in records])),
        median_act_ms=float(np.median(act_ms)),
        median_step_ms=float(np.median(np.concatenate([r.step_times_s for r in records])) * 1e3),
        plan_time_median_s=None if times is None else float(np.median(times)),
        plan_time_p95_s=None if times is None else float(np.percentile(times, 95)),
        act_p99_ms=float(np.percentile(act_ms, 99)),
        act_max_ms=float(act_ms.max()),
        act_share_over_aim=float(np.mean(act_ms > ACT_AIM_MS)),
        task_success=[bool(r.success) for r in records],
        family=family,
        first_seed=int(seeds[0]),
        mean_steps=float(np.mean([r.steps for r in records])),
        target_speed=float((env_kwargs or {}).get("target_speed", 0.0)),
        task_steps=[int(r.steps) for r in records],
        task_tip_path_m=[round(float(r.tip_path_m), 5) for r in records],
        real_time=real_time,
        task_held_steps=[int(r.held_steps) for r in records] if real_time else None,
        depth_noise_m=float((env_kwargs or {}).get("depth_noise_m", 0.0)),
        task_collided=[bool(r.collided) for r in records],
    )


def _success_cell(row: ObstacleRow | None, show_n: bool) -> str:
    if row is None:
        return "-"
    low, high = row.success_interval
    n = f" n={row.num_tasks}" if show_n else ""
    return f"{row.success_rate:.3f} ({low:.3f}-{high:.3f}){n}"


def _split_cell(row: ObstacleRow | None) -> str:
    if row is None:
        return "-"
    return " / ".join(str(v) for v in row.failure_split.values())


def table2_markdown(rows: list[ObstacleRow]) -> str:
    """Markdown of Table 2: one line per row name, the standard and blocked-path families side
    by side (success with its 95% Wilson interval, collision rate, failure split), the paper's
    number beside the standard column; "-" where a row has no result on a family."""
    by_name: dict[str, dict[str, ObstacleRow]] = {}
    for row in rows:
        by_name.setdefault(row.name, {})[row.family] = row
    counts = {f: {r.num_tasks for r in rows if r.family == f} for f in TABLE2_FAMILIES}
    header_n = {f: (f", n={next(iter(c))}" if len(c) == 1 else "") for f, c in counts.items()}
    lines = [
        f"| row | standard: success (95% CI{header_n['obstacles']}) | paper "
        f"| blocked: success (95% CI{header_n['blocked']}) | collision rate, standard / blocked "
        "| failures standard: collided, never reached / stalled, no collision / reached after "
        "collision | failures blocked (same split) | act (ms, median) "
        "| env step incl. rendering (ms) | planning (s, median / p95, standard / blocked) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, families in by_name.items():
        standard, blocked = families.get("obstacles"), families.get("blocked")
        paper = PAPER_TABLE2.get(name)
        any_row = standard or blocked
        collisions = " / ".join(
            "-" if r is None else f"{r.collision_rate:.3f}" for r in (standard, blocked)
        )
        planning = " / ".join(
            "-"
            if r is None or r.plan_time_median_s is None
            else f"{r.plan_time_median_s:.3f} / {r.plan_time_p95_s:.3f}"
            for r in (standard, blocked)
        )
        if planning == "- / -":
            planning = "-"
        lines.append(
            f"| {name} | {_success_cell(standard, not header_n['obstacles'])} "
            f"| {'-' if paper is None else paper} "
            f"| {_success_cell(blocked, not header_n['blocked'])} | {collisions} "
            f"| {_split_cell(standard)} | {_split_cell(blocked)} "
            f"| {any_row.median_act_ms:.4f} | {any_row.median_step_ms:.3f} | {planning} |"
        )
    return "\n".join(lines)


def write_table2(rows: list[ObstacleRow], out: Path, meta: dict[str, Any]) -> None:
    """`out`.json (rows + how they were made) and `out`.md."""
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {**meta, "rows": [row.__dict__ for row in rows]}
    out.with_suffix(".json").write_text(json.dumps(data, indent=2))
    out.with_suffix(".md").write_text(table2_markdown(rows) + "\n")
