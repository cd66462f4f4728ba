"""Would a finer depth sensor for the shield keep the 1-view hybrid off the obstacles? (A
screen on the validation episodes where it collided, choosing nothing by itself.)

    python results/stage2/shield/diagnose/depth_sensor.py --size 128 [--exact-depth] \
        [--seeds-from results/stage2/shield/diagnose/collisions.jsonl]

The policy acts on its own 64-pixel RGBD view as always; the shield, its unseen-space test and
the planner (session 14's 1-view hybrid: `depth_planner.HYBRID[1]` on 64 px) get a depth image of
the same camera rendered at `--size` pixels, quantised to 8 bits over the depth range like
the observation (about 9 mm a step) or, with `--exact-depth`, not quantised. Seeds as in
`goal_distance.py` (`--family`, `--num-tasks`, `--offset` into the validation range, or
`--seeds-from`). Appends one JSON line per episode to depth_sensor.jsonl and
prints success and collisions.
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
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.policies import load_policy
from clamgen.sim import constants as C
from clamgen.sim.render import MultiViewRenderer, depth_to_uint8

HERE = Path(__file__).resolve().parent


class OwnImages:
    """The policy acting on the observation's own images (`policy_images`)."""

    def __init__(self, policy) -> None:
        self.policy = policy
        self.agent = getattr(policy, "agent", None)

    def reset(self, env=None) -> None:
        self.policy.reset(env)

    def act(self, obs):
        return self.policy.act({**obs, "images": obs["policy_images"]})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128, help="the shield's depth image size")
    parser.add_argument("--exact-depth", action="store_true")
    parser.add_argument("--family", choices=("blocked", "obstacles"), default="blocked")
    parser.add_argument("--num-tasks", type=int, default=300)
    parser.add_argument("--offset", type=int, default=10_000)
    parser.add_argument("--seeds-from", type=Path, help="a JSON-lines file with a seed per line")
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy("residual-1view")
    views = env_kwargs["num_views"]
    # Session 14's hybrid, here given the finer depth as its images (as `fine_depth` does).
    guard = replace(HYBRID[views], fine_depth_size=0)
    shielded = guard.wrap(OwnImages(policy), views, args.size)
    env = ReachEnv(num_obstacles=2, task_family=args.family, **env_kwargs)
    scene = env.unwrapped.scene
    sensor = MultiViewRenderer(scene.model, scene.camera_ids[:views], args.size, args.size)
    near, far = C.DEPTH_RANGE_M

    def sense(obs):
        rgb, depth = sensor.render(scene.data)  # (the env's frames are current after a step)
        if args.exact_depth:  # depth in the 8-bit code's units, unrounded
            code = np.clip((depth - near) * (255.0 / (far - near)), 0, 255).astype(np.float32)
        else:
            code = depth_to_uint8(depth)
        images = np.concatenate([rgb.transpose(0, 3, 1, 2), code[:, None]], axis=1)
        return {**obs, "policy_images": obs["images"], "images": images}

    seeds = validation_seeds(args.num_tasks, args.offset, args.seeds_from)
    rows = []
    for seed in tqdm(seeds, desc=f"{args.family} validation tasks, shield sees {args.size} px"):
        obs, _ = env.reset(seed=int(seed))
        shielded.reset(env)
        collided = False
        while True:
            obs, _, terminated, truncated, info = env.step(shielded.act(sense(obs)))
            collided |= bool(info["collision"])
            if terminated or truncated:
                break
        rows.append(
            {
                "size": args.size,
                "exact_depth": args.exact_depth,
                "family": args.family,
                "seed": int(seed),
                "success": bool(info["is_success"]) and not collided,
                "collided": collided,
            }
        )
    with (HERE / "depth_sensor.jsonl").open("a") as f:
        f.writelines(json.dumps(row) + "\n" for row in rows)
    print(
        f"shield depth {args.size} px, {'exact' if args.exact_depth else '8-bit'}, {args.family}: "
        f"{len(rows)} tasks, success {np.mean([r['success'] for r in rows]):.3f}, "
        f"collided {sum(r['collided'] for r in rows)}"
    )


if __name__ == "__main__":
    main()
