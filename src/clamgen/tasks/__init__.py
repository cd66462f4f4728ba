"""Task sampling: targets, target motion, obstacles and start configurations.

A task family is a sampler `(rng, scene, num_obstacles, speed) -> Task`, named in
`TASK_FAMILIES`; an env id picks one (`clamgen.envs`).
"""

from collections.abc import Callable

import numpy as np

from clamgen.sim.scene import Scene
from clamgen.tasks.blocked import sample_blocked_task
from clamgen.tasks.reach import (
    SpeedSpec,
    Task,
    move_target,
    sample_obstacle_task,
    sample_reach_task,
    validate_speed,
)


def _reach(rng: np.random.Generator, scene: Scene, num_obstacles: int, speed: SpeedSpec) -> Task:
    return sample_reach_task(rng, scene, speed)


MIXED_BLOCKED_FRACTION = 0.5
"""Share of blocked-path tasks in the "mixed" family (the rest are standard obstacle tasks)."""


def _mixed(rng: np.random.Generator, scene: Scene, num_obstacles: int, speed: SpeedSpec) -> Task:
    """A blocked-path task with probability `MIXED_BLOCKED_FRACTION`, else a standard obstacle
    task: for training policies that must both avoid and reach where the way is free (on the
    standard tasks alone, the obstacles are rarely in the way)."""
    if rng.random() < MIXED_BLOCKED_FRACTION:
        return sample_blocked_task(rng, scene, num_obstacles, speed)
    return sample_obstacle_task(rng, scene, num_obstacles, speed)


TaskSampler = Callable[[np.random.Generator, Scene, int, SpeedSpec], Task]
# Family name -> (sampler, whether it needs obstacles).
TASK_FAMILIES: dict[str, tuple[TaskSampler, bool]] = {
    "reach": (_reach, False),
    "obstacles": (sample_obstacle_task, True),
    "blocked": (sample_blocked_task, True),
    "mixed": (_mixed, True),
}

__all__ = [
    "MIXED_BLOCKED_FRACTION",
    "TASK_FAMILIES",
    "Task",
    "TaskSampler",
    "move_target",
    "sample_blocked_task",
    "sample_obstacle_task",
    "sample_reach_task",
    "validate_speed",
]
