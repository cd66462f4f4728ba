"""Env steps per second (joint observations): CLAMGen on MuJoCo vs the paper's way in PyBullet.

Both sides run the same tasks (two obstacles) and the same random actions, with the same
kinematic stepping: the step's joint-space path is checked at the same sub-step resolution and
stops before contact. PyBullet sets joints with `resetJointState` and checks each obstacle and
the table with `getClosestPoints(distance=0)`, as the paper's implementation did.

    python benchmarks/env_steps.py [--num-steps 3000]

Prints both rates and the ratio, writes results/benchmarks/env_steps.csv. Target: >= 3x.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import best_rate, write_csv
from pybullet_scene import PyBulletScene

import clamgen  # noqa: F401
from clamgen.envs.reach_env import (
    COLLISION_CHECK_RESOLUTION_RAD,
    CONTROL_DT_S,
    MAX_JOINT_DELTA_RAD,
    STEP_PENALTY,
    SUCCESS_DISTANCE_M,
    ReachEnv,
)
from clamgen.robot import ur5
from clamgen.tasks import reach


class PyBulletReach:
    """The same kinematic reach step as `ReachEnv.step`, on PyBullet."""

    def __init__(self) -> None:
        self.scene = PyBulletScene()
        self.rng = np.random.default_rng(0)

    def reset(self, task: reach.Task) -> None:
        self.task = task
        self.scene.set_obstacles(task.obstacles)
        self.joints = task.start_joints.copy()
        self.scene.set_joints(self.joints)
        self.target = task.target_position_m.copy()
        self.velocity = task.target_velocity_mps.copy()

    def step(self, action: np.ndarray):
        action = np.clip(np.asarray(action, np.float64), -1, 1)
        wanted = np.clip(self.joints + action * MAX_JOINT_DELTA_RAD, *ur5.JOINT_LIMITS.T)
        delta = wanted - self.joints
        num_checks = max(1, int(np.ceil(np.abs(delta).max() / COLLISION_CHECK_RESOLUTION_RAD)))
        reached, collided = self.joints, False
        for k in range(1, num_checks + 1):
            joints = self.joints + delta * (k / num_checks)
            if self.scene.in_collision(joints):
                self.scene.set_joints(reached)
                collided = True
                break
            reached = joints
        executed = (reached - self.joints) / MAX_JOINT_DELTA_RAD
        self.joints = reached
        if self.velocity.any():
            self.target, self.velocity = reach.move_target(
                self.target, self.velocity, CONTROL_DT_S, self.task.speed, self.rng
            )
            self.scene.set_target(self.target)
        tip = self.scene.tip_position()
        distance = float(np.linalg.norm(tip - self.target))
        success = distance < SUCCESS_DISTANCE_M
        obs = {
            "observation": self.joints.astype(np.float32),
            "achieved_goal": tip.astype(np.float32),
            "desired_goal": self.target.astype(np.float32),
        }
        info = {"is_success": success, "collision": collided, "executed_action": executed}
        return obs, (0.0 if success else -STEP_PENALTY), success, False, info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-steps", type=int, default=3000)
    parser.add_argument("--episode-steps", type=int, default=100)
    args = parser.parse_args()

    env = ReachEnv(num_obstacles=2, max_episode_steps=None)
    reference = PyBulletReach()
    num_episodes = max(1, args.num_steps // args.episode_steps)
    tasks = []
    for seed in range(num_episodes):
        env.reset(seed=seed)
        tasks.append(env.task)
    actions = np.random.default_rng(0).uniform(-1, 1, (num_episodes, args.episode_steps, 6))
    total = num_episodes * args.episode_steps

    def run(sim):
        def rollouts():
            for task, episode_actions in zip(tasks, actions, strict=True):
                if sim is env:
                    env.reset(options={"task": task})
                else:
                    sim.reset(task)
                for action in episode_actions:
                    sim.step(action)

        return rollouts

    ours = best_rate(run(env), total)
    theirs = best_rate(run(reference), total)
    ratio = ours / theirs
    print(f"env steps/s, joint observations, 2 obstacles, {total} steps:")
    print(f"  CLAMGen (MuJoCo)                      {ours:10.0f}")
    print(f"  PyBullet resetJointState + getClosestPoints {theirs:10.0f}")
    print(f"  ratio {ratio:.2f}x (target >= 3x)")
    path = write_csv(
        "env_steps",
        [
            {
                "benchmark": "env_steps_joints",
                "clamgen_per_s": round(ours, 1),
                "pybullet_per_s": round(theirs, 1),
                "ratio": round(ratio, 2),
                "num_steps": total,
            }
        ],
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
