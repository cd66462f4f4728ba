"""Near-optimal reach baseline of the paper (section "Arm Reaching (No Obstacle)").

At every step: the analytic IK solutions of the *instantaneous* goal, the one nearest the current
joints (max-abs joint distance), and a step straight towards it in joint space at the same
joint-speed limit as the learned policies (the largest joint moves `MAX_JOINT_DELTA_RAD`, the
others in proportion). It knows nothing of obstacles, so it is a reference for obstacle-free
reaching and for path-length ratios.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from clamgen.envs.reach_env import MAX_JOINT_DELTA_RAD
from clamgen.robot.kinematics import solve_tip_position


class IKInterpolationPolicy:
    """Closed-loop joint-space interpolation to the nearest IK solution of the current goal.

    Needs `observation` (joints) and `desired_goal` in the observation (obs mode "joints" or
    "both").
    """

    def reset(self, env: Any | None = None) -> None:
        """Stateless: nothing to do."""

    def target_joints(self, joints: np.ndarray, goal_m: np.ndarray) -> np.ndarray | None:
        """The IK solution (6,) for `goal_m` nearest `joints`, or None when unreachable."""
        solutions = solve_tip_position(goal_m, reference_joints=joints)
        return solutions[0] if len(solutions) else None

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if "observation" not in obs:
            raise KeyError("IKInterpolationPolicy needs joint observations (obs_mode 'joints')")
        joints = np.asarray(obs["observation"], np.float64)
        target = self.target_joints(joints, np.asarray(obs["desired_goal"], np.float64))
        if target is None:
            return np.zeros(6, np.float32)
        delta = target - joints
        # Full speed on the joint with the farthest to go; arrive exactly when within a step.
        return (delta / max(np.max(np.abs(delta)), MAX_JOINT_DELTA_RAD)).astype(np.float32)
