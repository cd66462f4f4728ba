"""Arm keypoints for the networks agree with the kinematics module and lie along the links."""

import numpy as np
import torch

from clamgen.agents.geometry import (
    GOAL_DIRECTION_MIN_M,
    GOAL_OFFSET_SCALE_M,
    LONG_LINK_FRACTIONS,
    NUM_ARM_KEYPOINTS,
    arm_keypoints,
    goal_offset_features,
)
from clamgen.envs.reach_env import ReachEnv
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


def test_goal_offset_features_are_the_envs_tip_to_goal_offset_and_its_direction():
    env = ReachEnv(num_obstacles=2, task_family="blocked")
    joints, goals, tips = [], [], []
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        for _ in range(3):
            joints.append(obs["observation"])
            goals.append(obs["desired_goal"])
            tips.append(obs["achieved_goal"])
            obs = env.step(env.action_space.sample())[0]
    features = goal_offset_features(np.array(joints), np.array(goals))
    offset = np.array(goals) - np.array(tips)
    np.testing.assert_allclose(features[:, :3] * GOAL_OFFSET_SCALE_M, offset, atol=1e-4)
    distance = np.linalg.norm(offset, axis=1, keepdims=True)
    expected = offset / np.maximum(distance, GOAL_DIRECTION_MIN_M)
    np.testing.assert_allclose(features[:, 3:], expected, atol=1e-3)
    # At the goal the direction fades: a tip 1 cm away reads half a unit vector.
    near = goal_offset_features(joints[0], tips[0] + np.float32([0.01, 0.0, 0.0]))
    assert near.shape == (6,) and near.dtype == np.float32
    np.testing.assert_allclose(near[3:], [0.5, 0.0, 0.0], atol=2e-3)
