"""UR5 kinematics: DH facts, batched forward kinematics and closed-form inverse kinematics."""

from clamgen.robot.kinematics import (
    DEFAULT_TOOL_ORIENTATIONS,
    IK_POSITION_TOL_M,
    IK_ROTATION_TOL_RAD,
    default_tool_orientations,
    flange_pose,
    flange_to_tip,
    forward_kinematics,
    inverse_kinematics,
    joint_distance,
    link_frames,
    rotation_error,
    solve_tip_position,
    tip_pose,
    tip_position,
    tip_to_flange,
    wrap_joints,
)

__all__ = [
    "DEFAULT_TOOL_ORIENTATIONS",
    "IK_POSITION_TOL_M",
    "IK_ROTATION_TOL_RAD",
    "default_tool_orientations",
    "flange_pose",
    "flange_to_tip",
    "forward_kinematics",
    "inverse_kinematics",
    "joint_distance",
    "link_frames",
    "rotation_error",
    "solve_tip_position",
    "tip_pose",
    "tip_position",
    "tip_to_flange",
    "wrap_joints",
]
