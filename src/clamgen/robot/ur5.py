"""UR5 (CB3) facts: standard DH table, joint limits, collision capsules, suction gripper.

All lengths in metres, angles in radians. Frames follow the standard DH convention: frame 0 is
the robot base (the world origin of every scene), frame 6 is the tool flange.
"""

from __future__ import annotations

import numpy as np

# Standard DH parameters of the UR5 CB3 (Universal Robots' published table).
DH_D = np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823])
DH_A = np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])

NUM_JOINTS = 6
JOINT_NAMES = (
    "shoulder_pan",
    "shoulder_lift",
    "elbow",
    "wrist_1",
    "wrist_2",
    "wrist_3",
)
# Joint limits: +-2pi on every joint but the elbow, which is +-pi.
JOINT_LIMITS = np.array(
    [
        [-2 * np.pi, 2 * np.pi],
        [-2 * np.pi, 2 * np.pi],
        [-np.pi, np.pi],
        [-2 * np.pi, 2 * np.pi],
        [-2 * np.pi, 2 * np.pi],
        [-2 * np.pi, 2 * np.pi],
    ]
)
MAX_JOINT_SPEED_RAD_S = np.pi

# Collision capsule radii (measured) and link offsets.
SHOULDER_RADIUS_M = 0.060
UPPER_ARM_RADIUS_M = 0.054
ELBOW_RADIUS_M = 0.060
FOREARM_RADIUS_M = 0.040
WRIST_RADIUS_M = 0.045
SHOULDER_OFFSET_M = 0.13585
ELBOW_OFFSET_M = -0.1197

# Suction gripper (OnRobot VGC10-like): a cylinder on the flange; the tip, which is the
# end-effector for goals and paths, lies this far past the flange along the flange z axis.
GRIPPER_TIP_OFFSET_M = 0.10
GRIPPER_RADIUS_M = 0.035

# A comfortable "elbow up, tool down" configuration used as the default home pose.
# The workspace lies at +x of the base while a UR arm at q = 0 stretches along -x (a2, a3 < 0),
# so the shoulder pan is turned by about pi; the extra -0.183 rad (asin of the shoulder offset
# d4 over the wrist distance) puts the tip on the y = 0 plane. q2 + q3 + q4 = -pi/2 and
# q5 = -pi/2 point the tool z axis straight down. Tip (FK): (0.600, 0.000, 0.500) m, i.e. 10 cm
# above the top of the workspace box centred at (0.6, 0, 0.2); elbow at z = 0.484 m, above the
# shoulder-wrist line (elbow up). Values are the closed-form IK solution rounded to 1e-6 rad.
# (The earlier value [0, -pi/2, pi/2, -pi/2, -pi/2, 0] put the tip at (-0.487, -0.109, 0.332),
# behind the robot.)
HOME_JOINTS = np.array([2.958657, -1.192921, 0.663427, -1.041302, -1.570796, 0.0])
