"""Probe (session 49, training tasks; nothing piloted): the told hybrid's map lifting each
pixel's running mean of noisy depth instead of its last reading.

Needs `depth_average.patch` applied to the code of 1e1f310 (`git apply
results/stage2/noise/depth_average.patch`: `DepthGuard.average_frames`, `DepthAverage`, the
arm's pixels kept out of the means); without the patch only `FRAMES` = 0 runs. One JSON line
per episode on stdout (outcome, blocked act median, map points and how many lie farther than
2 / 5 cm from the true obstacles), then a summary line:

    python results/stage2/noise/average_probe.py VIEWS K FRAMES EPISODES FIRST [FAMILY]
    # session 49: 3 0.01 0|8|32 40 777000, and 3 0.0 0 40 777000 (exact depth)

Episodes reset with training seeds `TRAINING_SEEDS.start + FIRST + i`. The lines of session
49 are in `average_probe.jsonl` (fields as printed, with `views`, `noise_m`,
`average_frames`).
"""

import json
import sys
from dataclasses import replace

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.policies import load_policy
from clamgen.sim import constants as C

POLICIES = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}


def off_obstacles(points: np.ndarray, obstacles) -> np.ndarray:
    """Each point's distance (m) to the nearest true obstacle (axis-aligned boxes, upright
    cylinders)."""
    distance = np.full(len(points), np.inf)
    for kind, centre, half in zip(
        obstacles.kinds, obstacles.positions_m, obstacles.half_sizes_m, strict=True
    ):
        if kind == C.OBSTACLE_BOX:
            off = np.linalg.norm(np.maximum(np.abs(points - centre) - half, 0), axis=1)
        else:
            radial = np.linalg.norm(points[:, :2] - centre[:2], axis=1) - half[0]
            vertical = np.abs(points[:, 2] - centre[2]) - half[2]
            off = np.hypot(np.maximum(radial, 0), np.maximum(vertical, 0))
        distance = np.minimum(distance, off)
    return distance


def main() -> None:
    views, noise_m, frames = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    episodes, first = int(sys.argv[4]), int(sys.argv[5])
    family = sys.argv[6] if len(sys.argv) > 6 else "blocked"
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy(POLICIES[views])
    guard = replace(HYBRID[views], noise_m=noise_m)
    if frames:
        guard = replace(guard, average_frames=frames)
    hybrid, env_kwargs = guard.around(policy, env_kwargs)
    env = ReachEnv(num_obstacles=2, task_family=family, depth_noise_m=noise_m, **env_kwargs)
    lines = []
    for i in range(episodes):
        seed = TRAINING_SEEDS.start + first + i
        record = run_episode(env, hybrid, seed)
        points = hybrid.occupancy.points
        off = off_obstacles(points, env.unwrapped.scene.obstacles)
        line = {
            "seed": seed,
            "success": bool(record.success),
            "collided": bool(record.collided),
            "steps": int(record.steps),
            "act_ms": float(np.median(record.act_times_s) * 1e3),
            "points": len(points),
            "off2": int((off > 0.02).sum()),
            "off5": int((off > 0.05).sum()),
        }
        lines.append(line)
        print(json.dumps(line), flush=True)
    total = {key: sum(line[key] for line in lines) for key in lines[0] if key != "act_ms"}
    act = np.median([line["act_ms"] for line in lines])
    print(
        f"SUMMARY views={views} K={noise_m} frames={frames}: reached {total['success']}/"
        f"{episodes} collided {total['collided']} act median {act:.2f} points "
        f"{total['points'] / episodes:.0f} off2 {total['off2'] / episodes:.1f} off5 "
        f"{total['off5'] / episodes:.1f} steps {total['steps'] / episodes:.0f}"
    )


if __name__ == "__main__":
    main()
