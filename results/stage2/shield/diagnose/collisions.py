"""Where the 1-view depth shield's remaining collisions happen (a diagnosis on validation tasks,
choosing nothing by itself; it reads the true scene only to describe each collision).

    python results/stage2/shield/diagnose/collisions.py --num-tasks 900 [--shadow 0.05]

Runs `residual-1view` through the depth shield with the planner and the chosen unseen-space
setting on blocked validation tasks, and for every first collision of an episode prints: the
arm geom that touched, whether the arm was following a plan, the step, the distance of the
contact to the nearest kept surface point, and whether the contact lay in space the shield
took as hidden or as seen free. Appends one JSON line per collision to collisions.jsonl.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import torch
from tqdm import tqdm

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.policies import load_policy
from clamgen.experiments.shield import step_checks

VALIDATION_OFFSET = 10_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-tasks", type=int, default=900)
    parser.add_argument("--offset", type=int, default=VALIDATION_OFFSET)
    parser.add_argument("--shadow", type=float, default=0.05)
    parser.add_argument("--policy", default="residual-1view")
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy(args.policy)
    guard = replace(HYBRID[1], shadow_m=args.shadow, fine_depth_size=0)  # session 14's hybrid
    shielded = guard.wrap(policy, env_kwargs["num_views"], env_kwargs["image_size"])
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
    scene = env.unwrapped.scene
    model, data = scene.model, scene.data
    out = Path(__file__).with_name("collisions.jsonl")
    seeds = VALIDATION_SEEDS.seeds(args.num_tasks, VALIDATION_SEEDS.start + args.offset)
    collided = 0
    for seed in tqdm(seeds, desc="blocked validation tasks"):
        obs, _ = env.reset(seed=int(seed))
        shielded.reset(env)
        for step in range(10_000):
            joints = np.asarray(obs["observation"][:6], np.float64)
            action = shielded.act(obs)
            following = shielded.waypoints is not None
            obs, _, terminated, truncated, info = env.step(action)
            if info["collision"]:
                collided += 1
                first = next(q for q in step_checks(joints, action) if scene.in_collision(q))
                contact = data.contact[0]
                geoms = {model.geom(int(contact.geom1)).name, model.geom(int(contact.geom2)).name}
                point = np.array(contact.pos)
                kept = shielded.checker.points
                nearest = float(np.linalg.norm(kept - point, axis=1).min()) if len(kept) else None
                hidden = seen_free = None
                if shielded.shadow is not None:
                    hidden = bool(shielded.shadow.hidden_points(point[None])[0])
                    seen_free = not bool(shielded.shadow._behind_hiding_surface(point[None])[0])
                row = {
                    "seed": int(seed),
                    "step": step,
                    "geoms": sorted(geoms),
                    "following_plan": following,
                    "nearest_kept_m": nearest,
                    "contact_hidden": hidden,
                    "contact_seen_free": seen_free,
                    "depth_m": float(contact.dist),
                    "clearance_before": float(shielded.checker.clearance(joints, cap=0.05)),
                    "clearance_at_contact": float(shielded.checker.clearance(first, cap=0.05)),
                }
                print(json.dumps(row), flush=True)
                with out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
                scene.set_joints(np.asarray(obs["observation"][:6], np.float64))
                mujoco.mj_kinematics(model, data)
                break
            if terminated or truncated:
                break
    print(f"{collided} of {len(seeds)} episodes collided")


if __name__ == "__main__":
    main()
