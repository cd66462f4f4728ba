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


TaskSampler = Callable[[np.random.Generator, Scene, int, SpeedSpec], Task]
# Family name -> (sampler, whether it needs obstacles).
TASK_FAMILIES: dict[str, tuple[TaskSampler, bool]] = {
    "reach": (_reach, False),
    "obstacles": (sample_obstacle_task, True),
    "blocked": (sample_blocked_task, True),
}

__all__ = [
    "TASK_FAMILIES",
    "Task",
    "TaskSampler",
    "move_target",
    "sample_blocked_task",
    "sample_obstacle_task",
    "sample_reach_task",
    "validate_speed",
]
