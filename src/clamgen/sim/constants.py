"""Named facts of the CLAMGen scene: where things are, how big, and which geoms collide.

World frame = the UR5's DH base frame (origin at the base, z up). Lengths in metres.
"""

from __future__ import annotations

import numpy as np

# Table: its top lies just below the lowest reach target (z = 0.0), so the tip can reach every
# target while the table still bounds the workspace from below.
TABLE_TOP_Z_M = -0.03
# Thick on purpose: MuJoCo's capsule-box test misses a capsule that pierces a thin slab.
TABLE_HALF_SIZE_M = (0.9, 0.9, 0.25)
TABLE_CENTER_XY_M = (0.35, 0.0)

# Target: a red sphere, visual only. Its radius equals the success threshold, so the tip
# "touches" the target exactly when the episode succeeds.
TARGET_RADIUS_M = 0.02

# Number of obstacle slots compiled into the model; a task uses the first `num_obstacles`.
MAX_OBSTACLES = 4
OBSTACLE_BOX = 0
OBSTACLE_CYLINDER = 1
# Where unused obstacle slots are parked (far below the table, out of every camera's view).
PARKED_POSITION_M = np.array([0.0, 0.0, -10.0])

# Collision bits (MuJoCo: two geoms touch when contype_a & conaffinity_b or vice versa).
# Robot links never touch each other (self-collision is outside the task), obstacles and the
# table never touch each other; only robot-vs-environment contacts are generated.
OBSTACLE_BIT = 1
TABLE_BIT = 2

# Fixed cameras: (name, position, look-at point, vertical field of view in degrees).
# They look at the workspace from four sides and heights; experiments use the first 1, 2 or 3.
WORKSPACE_LOOKAT_M = (0.5, 0.0, 0.15)
CAMERAS: tuple[tuple[str, tuple[float, float, float], tuple[float, float, float], float], ...] = (
    ("front_right", (1.25, -0.7, 0.6), WORKSPACE_LOOKAT_M, 50.0),
    ("front_left", (1.25, 0.7, 0.4), WORKSPACE_LOOKAT_M, 50.0),
    ("top", (0.6, 0.0, 1.45), (0.45, 0.0, 0.1), 55.0),
    ("back", (-0.4, -0.5, 0.9), WORKSPACE_LOOKAT_M, 50.0),
)
NUM_CAMERAS = len(CAMERAS)
# Zoomed views (beyond the paper): a second camera at each view camera's position, turned to the
# target at every step (MuJoCo's "targetbody" mode), with this vertical field of view: the
# target's surroundings at about 4x the view's resolution (0.36 cm a pixel at 1.1 m and 64
# pixels, against 1.6 cm). Their names are the view cameras' with ZOOM_SUFFIX.
ZOOM_FOVY_DEG = 12.0
ZOOM_SUFFIX = "_zoom"

# Near / far clipping planes of every camera (metres). Metric depth saturates at the far plane.
CAMERA_NEAR_M = 0.02
CAMERA_FAR_M = 10.0
# Metric depth is stored in observations as uint8 over this range (values outside clip).
DEPTH_RANGE_M = (0.3, 2.5)

# The outside view used for videos and pictures (not a policy input).
OVERVIEW_CAMERA = ("overview", (1.3, -1.1, 0.9), (0.4, 0.0, 0.15), 45.0)
