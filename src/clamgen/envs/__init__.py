"""Gymnasium environments, registered as `CLAMGen/Reach-v0`, `CLAMGen/ReachObstacles-v0`,
`CLAMGen/ReachBlocked-v0` (obstacle tasks whose obstacle-blind path is blocked) and
`CLAMGen/ReachMixed-v0` (half blocked, half standard obstacle tasks: a training mix)."""

import gymnasium as gym

from clamgen.envs.reach_env import (
    CONTROL_DT_S,
    MAX_EPISODE_STEPS,
    MAX_JOINT_DELTA_RAD,
    SUCCESS_DISTANCE_M,
    EnvState,
    ReachEnv,
)

ENV_IDS = (
    "CLAMGen/Reach-v0",
    "CLAMGen/ReachObstacles-v0",
    "CLAMGen/ReachBlocked-v0",
    "CLAMGen/ReachMixed-v0",
)
# Env id -> (number of obstacles, task family in `clamgen.tasks.TASK_FAMILIES`).
ENV_TASKS = {
    "CLAMGen/Reach-v0": (0, "reach"),
    "CLAMGen/ReachObstacles-v0": (2, "obstacles"),
    "CLAMGen/ReachBlocked-v0": (2, "blocked"),
    "CLAMGen/ReachMixed-v0": (2, "mixed"),
}


def register_envs() -> None:
    """Register the CLAMGen environments with Gymnasium (idempotent)."""
    entry = "clamgen.envs.reach_env:ReachEnv"
    # Through `gym.make`, Gymnasium's TimeLimit truncates (`max_episode_steps=` overrides it);
    # a directly constructed ReachEnv truncates by itself.
    for env_id, (num_obstacles, family) in ENV_TASKS.items():
        if env_id not in gym.registry:
            kwargs = {"num_obstacles": num_obstacles, "task_family": family}
            gym.register(
                env_id,
                entry_point=entry,
                max_episode_steps=MAX_EPISODE_STEPS,
                kwargs={**kwargs, "max_episode_steps": None},
            )


register_envs()

__all__ = [
    "CONTROL_DT_S",
    "ENV_IDS",
    "ENV_TASKS",
    "MAX_EPISODE_STEPS",
    "MAX_JOINT_DELTA_RAD",
    "SUCCESS_DISTANCE_M",
    "EnvState",
    "ReachEnv",
    "register_envs",
]
