"""Arm keypoints for the networks agree with the kinematics module and lie along the links."""

import numpy as np
import torch

from clamgen.agents.geometry import LONG_LINK_FRACTIONS, NUM_ARM_KEYPOINTS, arm_keypoints
from clamgen.robot.kinematics import forward_kinematics


def test_keypoints_are_the_frame_origins_tip_and_points_along_the_long_links():
    joints = np.random.default_rng(0).uniform(-np.pi, np.pi, (16, 6))
    points = arm_keypoints(torch.as_tensor(joints)).numpy()
    assert points.shape == (16, NUM_ARM_KEYPOINTS, 3)
    origins = forward_kinematics(joints)[:, :, :3, 3]  # frames 1..6 and the tip
    np.testing.assert_allclose(points[:, :7], origins, atol=1e-5)
    n = len(LONG_LINK_FRACTIONS)
    for link, (a, b) in enumerate(((0, 1), (1, 2))):
        for j, fraction in enumerate(LONG_LINK_FRACTIONS):
            expected = origins[:, a] + fraction * (origins[:, b] - origins[:, a])
            np.testing.assert_allclose(points[:, 7 + link * n + j], expected, atol=1e-5)
