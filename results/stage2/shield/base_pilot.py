"""The pilot that led to session 42's control (README.md, "Session 42"): the base (no vision)
and the shipped residual through the same hybrid, on 30 blocked validation tasks.

    python results/stage2/shield/base_pilot.py [--views 3] [--num-tasks 30]

Offset 430000 into the validation range (a block no other run used). Prints, for each policy,
the blocked successes and the plans its hybrid made (tried / found a path).
"""

from __future__ import annotations

import argparse

import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.policies import load_policy

OFFSET = 430_000
SHIPPED = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=3, choices=tuple(SHIPPED))
    parser.add_argument("--num-tasks", type=int, default=30)
    args = parser.parse_args()
    torch.set_num_threads(1)
    guard = HYBRID[args.views]
    _, _, env_kwargs = load_policy(SHIPPED[args.views])  # the base sees the same views' env
    first = VALIDATION_SEEDS.start + OFFSET
    seeds = [int(s) for s in VALIDATION_SEEDS.seeds(args.num_tasks, first)]
    for name in ("base", SHIPPED[args.views]):
        policy, guarded_env = guard.around(load_policy(name)[0], env_kwargs)
        env = ReachEnv(num_obstacles=2, task_family="blocked", **guarded_env)
        records = evaluate(env, policy, seeds)
        env.close()
        successes = sum(r.success for r in records)
        print(
            f"{name} through the {args.views}-view hybrid: {successes} of {len(seeds)} blocked, "
            f"{policy.num_plans} plans, {policy.num_paths} with a path"
        )


if __name__ == "__main__":
    main()
