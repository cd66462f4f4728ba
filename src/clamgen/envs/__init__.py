"""Gymnasium environments, registered as `CLAMGen/Reach-v0` and `CLAMGen/ReachObstacles-v0`."""

import gymnasium as gym

from clamgen.envs.reach_env import (
    CONTROL_DT_S,
    MAX_EPISODE_STEPS,
    MAX_JOINT_DELTA_RAD,
    SUCCESS_DISTANCE_M,
    EnvState,
    ReachEnv,
)

ENV_IDS = ("CLAMGen/Reach-v0", "CLAMGen/ReachObstacles-v0")


def register_envs() -> None:
    """Register the CLAMGen environments with Gymnasium (idempotent)."""
    entry = "clamgen.envs.reach_env:ReachEnv"
    # Through `gym.make`, Gymnasium's TimeLimit truncates (`max_episode_steps=` overrides it);
    # a directly constructed ReachEnv truncates by itself.
    for env_id, num_obstacles in zip(ENV_IDS, (0, 2), strict=True):
        if env_id not in gym.registry:
            gym.register(
                env_id,
                entry_point=entry,
                max_episode_steps=MAX_EPISODE_STEPS,
                kwargs={"num_obstacles": num_obstacles, "max_episode_steps": None},
            )


register_envs()

__all__ = [
    "CONTROL_DT_S",
    "ENV_IDS",
    "MAX_EPISODE_STEPS",
    "MAX_JOINT_DELTA_RAD",
    "SUCCESS_DISTANCE_M",
    "EnvState",
    "ReachEnv",
    "register_envs",
]
