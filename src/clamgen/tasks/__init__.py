"""Task sampling: targets, target motion, obstacles and start configurations."""

from clamgen.tasks.reach import (
    Task,
    move_target,
    sample_obstacle_task,
    sample_reach_task,
    validate_speed,
)

__all__ = ["Task", "move_target", "sample_obstacle_task", "sample_reach_task", "validate_speed"]
