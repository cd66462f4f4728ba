"""Exploratory (session 43): why RRT on the depth map of one view stalls. Validation tasks
only; nothing is chosen on them.

    python results/stage2/shield/depth_rrt_unseen.py [--num-tasks 60]

`depth-rrt-1view` as shipped (the 1-view hybrid's shield and planner, with the unseen-space
test: the hand kept out of space no camera has seen free within 5 cm behind seen surfaces)
and the same without that test, on `--num-tasks` blocked validation tasks (offset 450000 into
the validation range). Prints and writes to `depth_rrt_unseen.jsonl`, per setting: successes,
collisions, stalls (neither reached nor collided), plans tried and paths found.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import HYBRID, rendered_views_env
from clamgen.experiments.evaluate import evaluate
from clamgen.policy import HoldStill

HERE = Path(__file__).resolve().parent
OFFSET = 450_000
SETTINGS = {
    "as shipped (unseen-space test)": replace(HYBRID[1], plan_first=True),
    "without the unseen-space test": replace(
        HYBRID[1], plan_first=True, shadow_m=None, shadow_behind_surfaces=False
    ),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-tasks", type=int, default=60)
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = VALIDATION_SEEDS.seeds(args.num_tasks, VALIDATION_SEEDS.start + OFFSET)
    out = HERE / "depth_rrt_unseen.jsonl"
    with out.open("w") as f:
        for words, guard in SETTINGS.items():
            policy, env_kwargs = guard.around(HoldStill(), rendered_views_env(1))
            env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
            records = evaluate(env, policy, seeds)
            env.close()
            line = {
                "setting": words,
                "num_tasks": len(records),
                "successes": sum(r.success for r in records),
                "collisions": sum(r.collided for r in records),
                "stalls": sum(not r.reached and not r.collided for r in records),
                "plans": policy.num_plans,
                "paths": policy.num_paths,
            }
            print(json.dumps(line), flush=True)
            f.write(json.dumps(line) + "\n")
    print("wrote", out)


if __name__ == "__main__":
    main()
