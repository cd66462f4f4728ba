"""Probe (session 49, training tasks): at each plan of the 3-view hybrid (exact depth), the
arm's clearance from the map and how many of the goal's IK solutions keep the 1 cm margin.

    python results/stage2/shield/goal_zone_probe/plan_time.py 777046 777087 777107 777127

(The offsets are into the training seeds; output in `plan_time.txt`.)
"""

import sys

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments import depth_planner
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.policies import load_policy
from clamgen.robot import ur5
from clamgen.robot.kinematics import solve_tip_position

MARGIN_M = 0.01


class Reporting(depth_planner.DepthShieldPlanner):
    def plan(self, joints: np.ndarray, goal: np.ndarray):
        solutions = solve_tip_position(goal, reference_joints=ur5.HOME_JOINTS)
        clear = np.array([self.checker.clearance(q, cap=MARGIN_M) for q in solutions])
        print(
            f"  plan: arm clearance {self.checker.clearance(joints, cap=MARGIN_M):.4f} m, "
            f"{int((clear >= MARGIN_M - 1e-6).sum())} of {len(solutions)} goal solutions keep "
            f"1 cm, the best {clear.max():.4f} m",
            flush=True,
        )
        path = super().plan(joints, goal)
        print(f"  -> {'a path' if path is not None else 'no path'}", flush=True)
        return path


def main() -> None:
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy("residual-3views")
    guard = depth_planner.HYBRID[3]
    views, size = env_kwargs["num_views"], env_kwargs["image_size"]
    hybrid = Reporting(
        policy, views, size, guard.margin_m, plan_checks=guard.plan_checks,
        track_m=guard.track_m, fine_depth_size=guard.fine_depth_size,
    )  # fmt: skip
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs | guard.env_kwargs())
    for offset in map(int, sys.argv[1:]):
        print(offset)
        record = run_episode(env, hybrid, TRAINING_SEEDS.start + offset)
        outcome = f"reached {record.success}, collided {record.collided}"
        print(f"{offset}: {outcome}, {record.steps} steps")


if __name__ == "__main__":
    main()
