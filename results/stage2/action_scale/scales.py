"""Score policies on validation tasks (never test tasks) with their actions scaled.

    python results/stage2/action_scale/scales.py POLICY [POLICY ...] --scales 1.0 0.8 0.6 \
        --offset 380000 --num-tasks 300 --out choice.jsonl

Each policy (a shipped name or a policy file) acts on `--num-tasks` blocked-path tasks and a
third as many standard obstacle tasks with validation seeds from `VALIDATION_SEEDS.start +
offset`, once per scale k, its action multiplied by k (`clamgen.policy.ScaledPolicy`, as
`clamgen eval --action-scale`). Appends one JSON line per policy, family and scale: successes,
collisions, mean steps and each task's success and collision, in seed order.

    python results/stage2/action_scale/scales.py --summarize confirm.jsonl

prints, per block, family and scale, the successes and collisions summed over the policies
scored there, and task by task against k = 1 the tasks only one of the two solves, with the
exact sign test's P (`clamgen.experiments.tables.paired_count`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.evaluate import evaluate, per_task
from clamgen.experiments.policies import load_policy
from clamgen.experiments.tables import paired_count
from clamgen.policy import ScaledPolicy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policies", nargs="*")
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0])
    parser.add_argument("--offset", type=int, help="into the validation seeds")
    parser.add_argument("--num-tasks", type=int, default=300, help="blocked tasks")
    parser.add_argument("--out", type=Path, help="JSON lines to append to")
    parser.add_argument("--summarize", type=Path, metavar="JSONL", help="score nothing")
    args = parser.parse_args()
    if args.summarize:
        summarize(args.summarize)
        return
    if not args.policies or args.offset is None or args.out is None:
        parser.error("name the policies, --offset and --out (or --summarize JSONL)")
    torch.set_num_threads(1)
    for name in args.policies:
        policy, _, env_kwargs = load_policy(name)
        for family, num_tasks in (("blocked", args.num_tasks), ("obstacles", args.num_tasks // 3)):
            env = ReachEnv(num_obstacles=2, task_family=family, **env_kwargs)
            seeds = VALIDATION_SEEDS.seeds(num_tasks, VALIDATION_SEEDS.start + args.offset)
            for scale in args.scales:
                tasks = per_task(evaluate(env, ScaledPolicy(policy, scale), seeds))
                row = {
                    "policy": str(name),
                    "family": family,
                    "scale": scale,
                    "first_seed": int(seeds[0]),
                    "num_tasks": num_tasks,
                    "success": sum(tasks["success"]),
                    "collided": sum(tasks["collided"]),
                    "mean_steps": round(float(np.mean(tasks["steps"])), 2),
                    "task_success": [int(s) for s in tasks["success"]],
                    "task_collided": [int(c) for c in tasks["collided"]],
                }
                print(
                    f"{name} {family} x{scale:g}: {row['success']} of {num_tasks}, "
                    f"{row['collided']} collided, {row['mean_steps']} steps",
                    flush=True,
                )
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
            env.close()


def summarize(path: Path) -> None:
    """Per block, family and scale: the sums over the policies scored, and against k = 1."""
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    groups: dict[tuple, list[dict]] = {}
    for row in lines:
        groups.setdefault((row["first_seed"], row["family"], row["scale"]), []).append(row)
    for (first_seed, family, scale), rows in sorted(groups.items(), key=lambda kv: kv[0][:2]):
        num = sum(row["num_tasks"] for row in rows)
        text = (
            f"{first_seed} {family:9s} x{scale:<4g} {len(rows)} policies: "
            f"{sum(row['success'] for row in rows)} of {num} succeed, "
            f"{sum(row['collided'] for row in rows)} collide, "
            f"{np.mean([row['mean_steps'] for row in rows]):.1f} steps"
        )
        full = {row["policy"]: row for row in groups.get((first_seed, family, 1.0), [])}
        if scale != 1.0 and all(row["policy"] in full for row in rows):
            count = paired_count(
                [s for row in rows for s in row["task_success"]],
                [s for row in rows for s in full[row["policy"]]["task_success"]],
            )
            text += (
                f"; against x1: {count.first_only} solved only at x{scale:g}, "
                f"{count.second_only} only at x1 (P {count.p_value:.3f})"
            )
        print(text)


if __name__ == "__main__":
    main()
