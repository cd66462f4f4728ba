"""Exploratory (session 43): a moving target on the obstacle tasks, where a plan to the
target's position goes stale. Validation tasks only; nothing is chosen on them.

    python results/stage2/shield/moving_targets.py [--views 2] [--num-tasks 40]

The shipped vision residual of each of `--views` alone and in its hybrid (`--depth-hybrid`),
and RRT on the depth map of the same views (`depth-rrt-*`), on `--num-tasks` validation tasks
(offset
450000 into the validation range) of each obstacle family with the target moving at 0, 0.05,
0.1 and 0.2 m/s (the paper's speeds; `ReachEnv(target_speed=...)`, reflected at the goal box's
faces). The blocked family's tasks are sampled so that the blind path to the target's first
position collides; a moving target may leave that position. One line per (views, family,
speed, row) in `moving_targets.jsonl` (the lines of the other numbers of views kept):
successes, collisions and the mean steps of the successes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.policies import load_policy, views_suffix

HERE = Path(__file__).resolve().parent
OFFSET = 450_000
SPEEDS = (0.0, 0.05, 0.1, 0.2)
ROWS = ("residual-{}", "residual-{} + hybrid", "depth-rrt-{}")
"""The rows by number of views (`views_suffix`)."""


def policy_of(row: str):
    policy, _, env_kwargs = load_policy(row.split(" + ")[0])
    if row.endswith("hybrid"):
        policy, env_kwargs = HYBRID[env_kwargs["num_views"]].around(policy, env_kwargs)
    return policy, env_kwargs


def measure(row: str, family: str, speed: float, seeds) -> dict:
    """One row on `seeds` of `family` with the target moving at `speed`."""
    policy, env_kwargs = policy_of(row)
    env = ReachEnv(num_obstacles=2, task_family=family, target_speed=speed, **env_kwargs)
    records = evaluate(env, policy, seeds)
    env.close()
    return {"family": family, "speed": speed, "row": row, **outcomes(records)}


def outcomes(records) -> dict:
    """Tasks, successes, collisions and the mean steps of the successes of some episodes."""
    solved = [r.steps for r in records if r.success]
    return {
        "num_tasks": len(records),
        "successes": len(solved),
        "collisions": sum(r.collided for r in records),
        "mean_steps_of_successes": float(np.mean(solved)) if solved else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-tasks", type=int, default=40)
    parser.add_argument("--views", type=int, nargs="+", default=[2], choices=(3, 2, 1))
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = VALIDATION_SEEDS.seeds(args.num_tasks, VALIDATION_SEEDS.start + OFFSET)
    out = HERE / "moving_targets.jsonl"
    kept = []
    if out.exists():
        lines = [json.loads(line) for line in out.read_text().splitlines()]
        kept = [line for line in lines if line["views"] not in args.views]
    with out.open("w") as f:
        for line in kept:
            f.write(json.dumps(line) + "\n")
        for views in args.views:
            for family in ("blocked", "obstacles"):
                for speed in SPEEDS:
                    for row in (row.format(views_suffix(views)) for row in ROWS):
                        line = {"views": views, **measure(row, family, speed, seeds)}
                        print(json.dumps(line), flush=True)
                        f.write(json.dumps(line) + "\n")
                        f.flush()
    print("wrote", out)


if __name__ == "__main__":
    main()
