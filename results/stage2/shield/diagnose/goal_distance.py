"""How far from the target the 1-view hybrid collides, and how far from it its failures end
(a diagnosis on validation tasks, choosing nothing by itself).

    python results/stage2/shield/diagnose/goal_distance.py --margin 0.01 --family blocked \
        --num-tasks 300 [--offset 10000] [--seeds-from collisions.jsonl]

Runs `residual-1view` through the depth shield (margin `--margin`) with the planner and the
chosen unseen-space setting, and per episode records: success, whether and at which step it
first collided, the tip's distance to the target there, and the tip's closest and final
distance to the target. A wider margin lowers collisions but costs success; if the collisions
happen far from the target and the extra failures end close to it, a margin that narrows near
the target would keep both. Appends one JSON line per episode to goal_distance.jsonl (with the
margin, family and seed) and prints a summary.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from diagnosis_seeds import validation_seeds
from tqdm import tqdm

from clamgen.envs import ReachEnv
from clamgen.experiments import depth_shield
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.policies import load_policy
from clamgen.sim import constants as C

HERE = Path(__file__).resolve().parent


def _distance(obs) -> float:
    return float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--margin", type=float, default=0.01)
    parser.add_argument("--family", choices=("blocked", "obstacles"), default="blocked")
    parser.add_argument("--num-tasks", type=int, default=300)
    parser.add_argument("--offset", type=int, default=10_000)
    parser.add_argument("--seeds-from", type=Path, help="a JSON-lines file with a seed per line")
    parser.add_argument("--policy", default="residual-1view")
    parser.add_argument(
        "--target-filter",
        type=float,
        default=depth_shield.TARGET_FILTER_M,
        help="points within this of the target sphere's surface are taken for target",
    )
    args = parser.parse_args()
    depth_shield.TARGET_REACH_M = C.TARGET_RADIUS_M + args.target_filter
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy(args.policy)
    guard = replace(HYBRID[1], margin_m=args.margin, fine_depth_size=0)  # session 14's hybrid
    shielded = guard.wrap(policy, env_kwargs["num_views"], env_kwargs["image_size"])
    env = ReachEnv(num_obstacles=2, task_family=args.family, **env_kwargs)
    seeds = validation_seeds(args.num_tasks, args.offset, args.seeds_from)
    rows = []
    for seed in tqdm(seeds, desc=f"{args.family} validation tasks, margin {args.margin}"):
        obs, _ = env.reset(seed=int(seed))
        shielded.reset(env)
        row = {"margin_m": args.margin, "target_filter_m": args.target_filter}
        row |= {"family": args.family, "seed": int(seed)}
        closest = _distance(obs)
        for step in range(10_000):
            before = _distance(obs)
            obs, _, terminated, truncated, info = env.step(shielded.act(obs))
            closest = min(closest, _distance(obs))
            if info["collision"] and "collision_step" not in row:
                row["collision_step"] = step
                row["collision_distance_m"] = before
                # The env stopped the arm before the colliding sub-step and only re-ran the
                # kinematics since, so the contacts are still that sub-step's.
                contact = np.array(env.unwrapped.scene.data.contact[0].pos)
                row["contact_to_target_m"] = float(np.linalg.norm(contact - obs["desired_goal"]))
            if terminated or truncated:
                break
        row |= {
            "success": bool(info["is_success"]) and "collision_step" not in row,
            "collided": "collision_step" in row,
            "closest_m": closest,
            "final_m": _distance(obs),
        }
        rows.append(row)
    with (HERE / "goal_distance.jsonl").open("a") as f:
        f.writelines(json.dumps(row) + "\n" for row in rows)
    collided = [r["collision_distance_m"] for r in rows if r["collided"]]
    failed = [r["final_m"] for r in rows if not r["success"] and not r["collided"]]
    print(
        f"margin {args.margin}, {args.family}, {len(rows)} tasks: success "
        f"{np.mean([r['success'] for r in rows]):.3f}, collided {len(collided)}"
    )
    for name, values in (("tip-target distance at collision", collided),
                         ("final tip-target distance of stalled failures", failed)):  # fmt: skip
        if values:
            q = np.percentile(values, [10, 25, 50, 75, 90])
            print(f"  {name}: n={len(values)}, quantiles 10/25/50/75/90 % {np.round(q, 3)}")


if __name__ == "__main__":
    main()
