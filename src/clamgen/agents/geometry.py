"""Arm geometry for the networks: points along the UR5's links from its joint angles (torch).

The privileged residual sees the obstacles' true poses, but whether a motion collides depends
on where the links are, which joint angles give only through forward kinematics. Handing the
network points along the arm (and, in `ObstacleEncoder`, each point's offset to each obstacle)
saves it from learning the kinematics first. The points are a function of the joints alone.
`goal_offset_features` does the same for the goal: the tip's offset to it, for any policy.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from clamgen.robot.kinematics import tip_position
from clamgen.robot.ur5 import DH_A, DH_ALPHA, DH_D, GRIPPER_TIP_OFFSET_M, NUM_JOINTS

# Fractions along the two long links (shoulder -> elbow: 0.425 m, elbow -> wrist: 0.392 m) at
# which extra points are placed, so that no part of the arm is more than ~5 cm from a point;
# the short wrist links are covered by their frame origins.
LONG_LINK_FRACTIONS = (0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875)
# DH frame indices (1-based origins) that bound the two long links.
_LONG_LINKS = ((1, 2), (2, 3))
NUM_ARM_KEYPOINTS = NUM_JOINTS + 1 + len(_LONG_LINKS) * len(LONG_LINK_FRACTIONS)
# `goal_offset_features`: the offset is given in units of GOAL_OFFSET_SCALE_M (about the goal
# box's half width, so the values are of order 1 like the normalised joints), and its direction
# as offset / max(distance, GOAL_DIRECTION_MIN_M): a unit vector until the tip is within the
# success distance (2 cm), shrinking to zero inside it.
GOAL_OFFSET_SCALE_M = 0.1
GOAL_DIRECTION_MIN_M = 0.02
NUM_GOAL_OFFSET_FEATURES = 6


def _dh(theta: torch.Tensor, d: float, a: float, alpha: float) -> torch.Tensor:
    """Standard DH transforms Rz(theta) Tz(d) Tx(a) Rx(alpha), (B, 4, 4)."""
    ct, st = torch.cos(theta), torch.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    zero, one = torch.zeros_like(theta), torch.ones_like(theta)
    rows = (
        (ct, -st * ca, st * sa, a * ct),
        (st, ct * ca, -ct * sa, a * st),
        (zero, zero + sa, zero + ca, zero + d),
        (zero, zero, zero, one),
    )
    return torch.stack([torch.stack(row, -1) for row in rows], -2)


def arm_keypoints(joints: torch.Tensor) -> torch.Tensor:
    """Points along the arm in the base (= world) frame, (B, `NUM_ARM_KEYPOINTS`, 3).

    joints: (B, 6) radians. The points: the origins of DH frames 1..6 (shoulder, elbow, the
    three wrists, flange), the suction tip, then `LONG_LINK_FRACTIONS` of the way along the
    upper arm and along the forearm.
    """
    joints = joints.to(torch.float32)
    pose = None
    origins = []
    for i in range(NUM_JOINTS):
        link = _dh(joints[:, i], float(DH_D[i]), float(DH_A[i]), float(DH_ALPHA[i]))
        pose = link if pose is None else pose @ link
        origins.append(pose[:, :3, 3])
    origins.append(pose[:, :3, 3] + GRIPPER_TIP_OFFSET_M * pose[:, :3, 2])
    fractions = torch.tensor(LONG_LINK_FRACTIONS, device=joints.device).view(1, -1, 1)
    along = [
        origins[a - 1][:, None] + fractions * (origins[b - 1] - origins[a - 1])[:, None]
        for a, b in _LONG_LINKS
    ]
    return torch.cat([torch.stack(origins, 1), *along], 1)


def goal_offset_features(joints: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """The tip's offset to the goal, (B, `NUM_GOAL_OFFSET_FEATURES`) float32: the offset goal -
    tip (world frame) over `GOAL_OFFSET_SCALE_M`, then its direction (offset over the larger of
    its length and `GOAL_DIRECTION_MIN_M`).

    joints: (B, 6) radians; goal: (B, 3) metres. The tip comes from the joints by forward
    kinematics (`clamgen.robot.kinematics.tip_position`: the env's `achieved_goal`, to float
    precision), so a policy reading these knows where the goal lies from its tip without
    learning the kinematics: near the goal, a few centimetres are a small difference of large
    normalised inputs otherwise. A function of observations (no gradient flows through it),
    in numpy: at batch 1 a twentieth of the cost of the same kinematics as torch operations.
    """
    offset = np.asarray(goal, np.float64) - tip_position(np.asarray(joints, np.float64))
    distance = np.maximum(np.linalg.norm(offset, axis=-1, keepdims=True), GOAL_DIRECTION_MIN_M)
    return np.concatenate([offset / GOAL_OFFSET_SCALE_M, offset / distance], -1).astype(np.float32)
