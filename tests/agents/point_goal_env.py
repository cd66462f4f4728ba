"""A 2D point-mass goal-reaching env with the CLAMGen env contract, for agent and replay tests.

Observation: ``observation`` = point position (2,) float32 in [-1, 1]^2, ``achieved_goal`` = the
same position, ``desired_goal`` = target (2,) float32 in [-0.8, 0.8]^2. Action in [-1, 1]^2 moves
the point by at most ``STEP_SIZE`` per axis; the box clips the move, which ``executed_action``
reports. Reward -0.01 per step, 0 and terminated on success (within ``SUCCESS_DISTANCE``), plus
``collision_penalty * collision``; the strip ``x > WALL_X`` counts as a collision (the point is
stopped at the wall). Truncation after ``max_steps``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

STEP_SIZE = 0.1
SUCCESS_DISTANCE = 0.05
STEP_REWARD = -0.01
WALL_X = 0.95


def collision_flags(info: Any, shape: tuple[int, ...]) -> np.ndarray:
    """Collision flags of ``shape`` from None, a dict of arrays, or a sequence of dicts."""
    if info is None:
        return np.zeros(shape, dtype=bool)
    if isinstance(info, Mapping):
        return np.broadcast_to(np.asarray(info.get("collision", False), dtype=bool), shape)
    if isinstance(info, Sequence):
        return np.array([bool(i.get("collision", False)) for i in info]).reshape(shape)
    raise TypeError(f"unsupported info {type(info).__name__}")


class PointGoalEnv(gym.Env):
    """2D point reaching a target; see the module docstring."""

    def __init__(self, max_steps: int = 50, collision_penalty: float = 0.0) -> None:
        self.max_steps = max_steps
        self.collision_penalty = collision_penalty
        box = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.observation_space = spaces.Dict(
            {"observation": box, "achieved_goal": box, "desired_goal": box}
        )
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._pos = np.zeros(2, np.float32)
        self._goal = np.zeros(2, np.float32)
        self._steps = 0

    def compute_reward(
        self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any
    ) -> np.ndarray:
        distance = np.linalg.norm(np.asarray(achieved_goal) - desired_goal, axis=-1)
        reward = np.where(distance < SUCCESS_DISTANCE, 0.0, STEP_REWARD)
        return reward + self.collision_penalty * collision_flags(info, distance.shape)

    def _obs(self) -> dict[str, np.ndarray]:
        return {
            "observation": self._pos.copy(),
            "achieved_goal": self._pos.copy(),
            "desired_goal": self._goal.copy(),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        self._pos = self.np_random.uniform(-0.8, 0.8, 2).astype(np.float32)
        self._goal = self.np_random.uniform(-0.8, 0.8, 2).astype(np.float32)
        self._steps = 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        action = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        target = np.clip(self._pos + STEP_SIZE * action, -1.0, 1.0)
        collision = bool(target[0] > WALL_X)
        target[0] = min(target[0], WALL_X)
        executed = (target - self._pos) / STEP_SIZE
        self._pos = target.astype(np.float32)
        self._steps += 1
        info = {"collision": collision, "executed_action": executed.astype(np.float32)}
        reward = float(self.compute_reward(self._pos, self._goal, info))
        success = bool(np.linalg.norm(self._pos - self._goal) < SUCCESS_DISTANCE)
        info["is_success"] = success
        return self._obs(), reward, success, self._steps >= self.max_steps, info
