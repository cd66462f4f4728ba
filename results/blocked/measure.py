"""Measure the blocked-path task family on held-out tasks: does every task need avoidance?

On `--num-tasks` tasks of `CLAMGen/ReachBlocked-v0` (test seeds from TEST_SEEDS.start), checks
each task's start (collision-free) and goal (a collision-free IK solution), and rolls out
obstacle-blind IK interpolation and RRT with the full scene model (`clamgen.baselines`).
Targets (issue: blocked-path benchmark): IK interpolation fails on >= 95%, RRT succeeds on
>= 99%.

    python results/blocked/measure.py [--num-tasks 500]

Writes results/blocked/measure.json (summary and the seeds of every exception) and prints it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from clamgen.baselines import IKInterpolationPolicy, RRTPolicy
from clamgen.envs import ReachEnv
from clamgen.experiments.config import TEST_SEEDS, check_table_seeds
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.tables import wilson_interval
from clamgen.tasks.reach import collision_free_solutions

OUT = Path(__file__).resolve().parent / "measure.json"


def rate(flags: list[bool]) -> dict:
    low, high = wilson_interval(int(sum(flags)), len(flags))
    return {"rate": float(np.mean(flags)), "wilson95": [round(low, 4), round(high, 4)]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-tasks", type=int, default=500)
    args = parser.parse_args()
    seeds = check_table_seeds(TEST_SEEDS.start, args.num_tasks)
    env = ReachEnv(num_obstacles=2, task_family="blocked")

    start_free, goal_free = [], []
    tic = time.perf_counter()
    for seed in seeds:
        env.reset(seed=int(seed))
        task = env.task
        start_free.append(not env.scene.in_collision(task.start_joints))
        goal_free.append(len(collision_free_solutions(env.scene, task.target_position_m)) > 0)
    check_s = time.perf_counter() - tic

    tic = time.perf_counter()
    ik = evaluate(env, IKInterpolationPolicy(), seeds)
    ik_s = time.perf_counter() - tic
    tic = time.perf_counter()
    rrt_policy = RRTPolicy()
    rrt = evaluate(env, rrt_policy, seeds)
    rrt_s = time.perf_counter() - tic

    summary = {
        "env_id": "CLAMGen/ReachBlocked-v0",
        "num_tasks": args.num_tasks,
        "seeds": [int(seeds[0]), int(seeds[-1])],
        "command": "python results/blocked/measure.py " + " ".join(sys.argv[1:]),
        "start_collision_free": rate(start_free),
        "goal_has_collision_free_ik_solution": rate(goal_free),
        "ik_interpolation": {
            "failure": rate([not r.success for r in ik]),
            "collided": rate([r.collided for r in ik]),
            "success_seeds": [r.seed for r in ik if r.success],
            "failed_without_collision_seeds": [
                r.seed for r in ik if not r.success and not r.collided
            ],
            "seconds": round(ik_s, 1),
        },
        "rrt_full_model": {
            "success": rate([r.success for r in rrt]),
            "failed_seeds": [r.seed for r in rrt if not r.success],
            "seconds": round(rrt_s, 1),
        },
        "reset_and_check_seconds": round(check_s, 1),
        "targets": {"ik_interpolation_failure": ">= 0.95", "rrt_success": ">= 0.99"},
    }
    OUT.write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
