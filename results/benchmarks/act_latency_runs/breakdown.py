"""Where an escape row's act time goes: each part of the act, timed inside live episodes.

    python results/benchmarks/act_latency_runs/breakdown.py [--views 3 2 1] [--num-tasks 15]

The shipped policy of each number of views acts through the escape rows' wrapper
(`depth_planner.ESCAPES`, `clamgen eval --depth-escapes`) on `--num-tasks` blocked validation
tasks (offset 420000 into the validation range: timing only, nothing is chosen on them), as an
evaluation runs it: the env renders the next views between acts. Each act is split into the
obstacle map's update from the depth (`DepthOccupancy.update`), the unseen-space map's update
(`ArmShadow.update`), the policy's forward (`SACPolicy.act`, inside `StallBurst`; an escape
step skips it) and the shield's check of the chosen action (`DepthShield.shield`); "rest" is
what the wrapper does around them. Prints, per part, the median, 90th and 99th percentile and
the mean over all acts and over the acts longer than the 2 ms aim (`tables.ACT_AIM_MS`).
The parts are timed by wrapping those methods, which adds a few microseconds an act.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import ESCAPES
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.machine import describe
from clamgen.experiments.policies import load_policy
from clamgen.experiments.tables import ACT_AIM_MS

POLICIES = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}
OFFSET = 420_000
PARTS = ("act", "policy", "map", "unseen", "shield", "rest")


class PartTimes:
    """Wall-clock seconds of each timed part during the current act."""

    def __init__(self) -> None:
        self.now: dict[str, float] = {}
        self.acts: list[dict[str, float]] = []

    def wrap(self, owner, method: str, part: str) -> None:
        inner = getattr(owner, method)

        def timed(*args, **kwargs):
            tic = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.now[part] = self.now.get(part, 0.0) + time.perf_counter() - tic

        setattr(owner, method, timed)

    def wrap_act(self, wrapper) -> None:
        inner = wrapper.act

        def act(obs):
            self.now = {}
            tic = time.perf_counter()
            action = inner(obs)
            self.now["act"] = time.perf_counter() - tic
            named = sum(self.now.get(p, 0.0) for p in ("policy", "map", "unseen", "shield"))
            self.now["rest"] = self.now["act"] - named
            self.acts.append(self.now)
            return action

        wrapper.act = act

    def table(self) -> dict[str, np.ndarray]:
        return {p: np.array([a.get(p, 0.0) for a in self.acts]) * 1e3 for p in PARTS}


def run(views: int, num_tasks: int) -> str:
    policy, _, env_kwargs = load_policy(POLICIES[views])
    guard = ESCAPES[views]
    wrapper, env_kwargs = guard.around(policy, env_kwargs)
    times = PartTimes()
    times.wrap(wrapper.occupancy, "update", "map")
    if wrapper.shadow is not None:
        times.wrap(wrapper.shadow, "update", "unseen")
    times.wrap(wrapper.policy.policy, "act", "policy")  # inside StallBurst
    times.wrap(wrapper, "shield", "shield")
    times.wrap_act(wrapper)
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
    first = VALIDATION_SEEDS.start + OFFSET
    records = evaluate(env, wrapper, [int(s) for s in VALIDATION_SEEDS.seeds(num_tasks, first)])
    env.close()
    parts = times.table()
    slow = parts["act"] > ACT_AIM_MS
    lines = [
        f"{views} view(s), {POLICIES[views]} + escapes: {len(slow)} acts on {len(records)} "
        f"blocked tasks, {slow.mean():.2f} of them over {ACT_AIM_MS} ms",
        "  part      median     p90     p99    mean  mean, acts > aim",
    ]
    for part in PARTS:
        values = parts[part]
        median, p90, p99 = np.percentile(values, [50, 90, 99])
        over = values[slow].mean() if slow.any() else float("nan")
        lines.append(
            f"  {part:8s} {median:7.2f} {p90:7.2f} {p99:7.2f} {values.mean():7.2f} {over:17.2f}"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, nargs="+", default=[3, 2, 1], choices=(3, 2, 1))
    parser.add_argument("--num-tasks", type=int, default=15)
    args = parser.parse_args()
    if args.num_tasks < 1:
        parser.error(f"--num-tasks must be >= 1, got {args.num_tasks}")
    torch.set_num_threads(1)
    print(f"machine: {describe()}; ms per act")
    for views in args.views:
        print(run(views, args.num_tasks), flush=True)


if __name__ == "__main__":
    main()
