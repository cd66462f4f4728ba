"""Wrappers that present CLAMGen observations in the layouts other libraries expect.

`StackedViews` turns the `images` entry, (V, 4, H, W) uint8 (views x RGBD x rows x columns),
into one channel-first image (V * 4, H, W) uint8: channel 4 * v + c is channel c (R, G, B,
depth) of view v. That is the layout Stable-Baselines3 recognises as an image
(`stable_baselines3.common.preprocessing.is_image_space`), so its `MultiInputPolicy` encodes
the views with a CNN (NatureCNN) instead of flattening them into an MLP, which costs about 10x
in training time per step at 2 views of 64 px.

    env = StackedViews(gym.make("CLAMGen/ReachObstacles-v0", num_views=2, image_size=64,
                                obs_mode="both"))
    env.observation_space["images"]  # Box(0, 255, (8, 64, 64), uint8)

SB3 tells channel-first from channel-last by the smallest dimension, so keep `image_size`
above V * 4 (SB3's NatureCNN also needs at least 36 px).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

IMAGES_KEY = "images"


class StackedViews(gym.ObservationWrapper):
    """Stacks the views of `obs["images"]` channel-first: (V, 4, H, W) -> (V * 4, H, W) uint8.

    Every other observation entry, the action space, rewards and `compute_reward` pass through
    unchanged, so goal-conditioned tools (HER buffers) work on the wrapped env as on the env.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, gym.spaces.Dict) or IMAGES_KEY not in space.spaces:
            raise ValueError(
                "StackedViews needs a Dict observation with 'images' "
                "(make the env with num_views >= 1 and obs_mode 'images' or 'both')"
            )
        images = space[IMAGES_KEY]
        if len(images.shape) != 4:
            raise ValueError(f"'images' must be (V, C, H, W), got shape {images.shape}")
        num_views, channels, height, width = images.shape
        shape = (num_views * channels, height, width)
        stacked = gym.spaces.Box(0, 255, shape, np.uint8)
        self.observation_space = gym.spaces.Dict({**space.spaces, IMAGES_KEY: stacked})

    def observation(self, observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        images = observation[IMAGES_KEY]
        return {**observation, IMAGES_KEY: images.reshape(-1, *images.shape[-2:])}

    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """The wrapped env's vectorised reward (goals are not part of the image layout)."""
        return self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)


def unstack_views(images: np.ndarray, num_views: int) -> np.ndarray:
    """Inverse of `StackedViews`: (..., V * 4, H, W) -> (..., V, 4, H, W), a view of the input."""
    images = np.asarray(images)
    *lead, channels, height, width = images.shape
    if channels % num_views:
        raise ValueError(f"{channels} channels do not split into {num_views} views")
    return images.reshape(*lead, num_views, channels // num_views, height, width)
