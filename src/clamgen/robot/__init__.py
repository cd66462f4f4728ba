"""UR5 kinematics: DH facts, batched forward kinematics and closed-form inverse kinematics.

The package re-exports `clamgen.robot.kinematics`'s public names (its `__all__`)."""

from clamgen.robot import kinematics
from clamgen.robot.kinematics import *  # noqa: F403

__all__ = kinematics.__all__
