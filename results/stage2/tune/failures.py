"""How a policy fails on blocked-path validation tasks: collision timing and final distance.

    python results/stage2/tune/failures.py runs/mixed-privileged/policy.pt --num-tasks 25

Validation seeds VALIDATION_SEEDS.start + FAILURE_OFFSET + i (never test seeds). One line per
task, then the counts: successes, failures that collided (and how many of those collided on
every later step, i.e. stayed pressed against the obstacle), failures without a collision.
"""

import argparse

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.policies import load_policy

FAILURE_OFFSET = 20_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy")
    parser.add_argument("--num-tasks", type=int, default=25)
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy(args.policy)
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
    seeds = VALIDATION_SEEDS.seeds(args.num_tasks, VALIDATION_SEEDS.start + FAILURE_OFFSET)
    counts = {"success": 0, "collided": 0, "pressed": 0, "first_step": 0, "no_collision": 0}
    for seed in seeds:
        steps = []  # (collided, distance) per step, from the rollout loop's hook

        def hook(obs, info, done, steps=steps):
            if info is not None:
                steps.append((bool(info["collision"]), float(info["distance_m"])))

        record = run_episode(env, policy, int(seed), on_step=hook)
        flags = np.array([collided for collided, _ in steps], bool)
        first = int(np.argmax(flags)) if flags.any() else None
        print(
            f"seed {seed}: success {record.success}, steps {record.steps}, first collision "
            f"{first}, colliding steps {int(flags.sum())}, final distance "
            f"{steps[-1][1]:.3f} m"
        )
        if record.success:
            counts["success"] += 1
        elif first is None:
            counts["no_collision"] += 1
        else:
            counts["collided"] += 1
            counts["pressed"] += bool(flags[first:].all())
            counts["first_step"] += first == 0
    print(
        f"{len(seeds)} tasks: {counts['success']} successes; failures: {counts['collided']} "
        f"collided ({counts['pressed']} on every step after the first contact, "
        f"{counts['first_step']} from the first step), {counts['no_collision']} without a "
        "collision"
    )


if __name__ == "__main__":
    main()
