"""A goal-conditioned env that is not a CLAMGen env, registered on import, for the tests of
training and evaluating on other envs through `--env.env-id point_reach_env:PointReach-v0`.

A point in [-1, 1]^3 moves by at most `STEP_SIZE` per axis towards a goal; success within
`SUCCESS_DISTANCE`. Like many goal envs (panda-gym's PandaReach, for one) it reports no
collisions, and its action has 3 dimensions where a UR5's has 6. `PointReach-v0` renders
`rgb_array` frames (a top view); `PointReachNoFrames-v0` is the same env without rendering.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

STEP_SIZE = 0.1
SUCCESS_DISTANCE = 0.1
FRAME_SIZE = 64


class PointReachEnv(gym.Env):
    """3D point reaching a goal; see the module docstring."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None) -> None:
        self.render_mode = render_mode
        box = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.observation_space = spaces.Dict(
            {"observation": box, "achieved_goal": box, "desired_goal": box}
        )
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self._pos = np.zeros(3, np.float32)
        self._goal = np.zeros(3, np.float32)

    def compute_reward(self, achieved_goal, desired_goal, info: Any) -> np.ndarray:
        distance = np.linalg.norm(np.asarray(achieved_goal) - desired_goal, axis=-1)
        return np.where(distance < SUCCESS_DISTANCE, 0.0, -1.0).astype(np.float32)

    def _obs(self) -> dict[str, np.ndarray]:
        return {
            "observation": self._pos.copy(),
            "achieved_goal": self._pos.copy(),
            "desired_goal": self._goal.copy(),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._pos = self.np_random.uniform(-0.8, 0.8, 3).astype(np.float32)
        self._goal = self.np_random.uniform(-0.8, 0.8, 3).astype(np.float32)
        return self._obs(), {}

    def step(self, action: np.ndarray):
        action = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        if action.shape != (3,):
            raise ValueError(f"action must have shape (3,), got {action.shape}")
        self._pos = np.clip(self._pos + STEP_SIZE * action, -1.0, 1.0).astype(np.float32)
        success = bool(np.linalg.norm(self._pos - self._goal) < SUCCESS_DISTANCE)
        reward = float(self.compute_reward(self._pos, self._goal, None))
        return self._obs(), reward, success, False, {"is_success": success}

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        frame = np.full((FRAME_SIZE, FRAME_SIZE, 3), 30, np.uint8)
        for point, colour in ((self._goal, (230, 40, 40)), (self._pos, (240, 240, 240))):
            col, row = ((point[:2] + 1.0) / 2.0 * (FRAME_SIZE - 1)).astype(int)
            frame[max(row - 2, 0) : row + 3, max(col - 2, 0) : col + 3] = colour
        return frame


class PointReachNoFramesEnv(PointReachEnv):
    """`PointReachEnv` that renders nothing."""

    metadata: ClassVar[dict] = {"render_modes": []}


for _id, _entry in (
    ("PointReach-v0", PointReachEnv),
    ("PointReachNoFrames-v0", PointReachNoFramesEnv),
):
    if _id not in gym.registry:
        gym.register(_id, entry_point=_entry, max_episode_steps=30)
