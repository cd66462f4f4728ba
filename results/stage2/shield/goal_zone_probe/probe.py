"""Probe (session 49, training tasks): where the 3-view hybrid fails on blocked tasks, and the
planner's goal zone (`--depth-goal-zone-m`). Nothing here chose a setting but the zone to pilot
(`../goal_zone_test.py`); the lines are in `probe.jsonl`.

    python results/stage2/shield/goal_zone_probe/probe.py run K ZONE 160 777040 > lines
        # K = 0 / 0.01 (told), ZONE = 0 (committed, with the map's diagnostics) or 0.1
    python results/stage2/shield/goal_zone_probe/probe.py true-clearance 46 73 87 ...
        # the goal's true clearance on those task offsets (MuJoCo geom distances)

`run`: per episode (training seed `TRAINING_SEEDS.start + FIRST + i`, blocked) the outcome,
plans tried / paths found, and with ZONE = 0 the final distance, the arm's clearance from the
map, and how many of the goal's IK solutions keep 1 cm from the final map.
"""

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.policies import load_policy
from clamgen.robot import ur5
from clamgen.robot.kinematics import solve_tip_position

MARGIN_M = 0.01


def run(noise_m: float, zone_m: float, episodes: int, first: int) -> None:
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy("residual-3views")
    guard = replace(HYBRID[3], noise_m=noise_m, goal_zone_m=zone_m)
    hybrid, env_kwargs = guard.around(policy, env_kwargs)
    env = ReachEnv(num_obstacles=2, task_family="blocked", depth_noise_m=noise_m, **env_kwargs)
    for i in range(episodes):
        seed = TRAINING_SEEDS.start + first + i
        plans, paths = hybrid.num_plans, hybrid.num_paths
        record = run_episode(env, hybrid, seed)
        line = {
            "seed": seed,
            "success": bool(record.success),
            "collided": bool(record.collided),
            "steps": int(record.steps),
            "plans": hybrid.num_plans - plans,
            "paths": hybrid.num_paths - paths,
        }
        if not zone_m:
            scene = env.unwrapped.scene
            goal = scene.target_position
            solutions = solve_tip_position(goal, reference_joints=ur5.HOME_JOINTS)
            clear = [hybrid.checker.clearance(q, cap=0.05) >= MARGIN_M for q in solutions]
            line |= {
                "distance": round(float(np.linalg.norm(scene.tip_position() - goal)), 3),
                "arm_clearance": round(hybrid.checker.clearance(scene.joints, cap=0.05), 3),
                "points": len(hybrid.occupancy.points),
                "goal_solutions": len(solutions),
                "goal_solutions_clear_1cm": int(np.sum(clear)),
            }
        print(json.dumps(line), flush=True)


def true_clearance(offsets: list[int]) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from goal_clearance import solution_clearances  # (../goal_clearance.py)

    env = ReachEnv(num_obstacles=2, task_family="blocked")
    for offset in offsets:
        best = solution_clearances(env, TRAINING_SEEDS.start + offset)
        print(
            f"{offset}: {len(best)} goal solutions, best true clearance {best.max():.4f} m, "
            f">= 1 cm: {(best >= 0.01).sum()}, >= 5 mm: {(best >= 0.005).sum()}, "
            f"> 0: {(best > 0).sum()}"
        )


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
    else:
        true_clearance([int(x) for x in sys.argv[2:]])
