"""Reach tasks: where the target starts and how it moves, where obstacles go, where the arm starts.

Paper, section "Experimental Results": the reach workspace is a 0.4 m box centred at
(0.6, 0, 0.2) m; targets move at 0 / 5 / 10 / 20 cm/s in a random direction (reflected at the
box faces here), or switch among those speeds ("variable"). With obstacles, two boxes or
cylinders are placed first, then a goal is accepted only if some IK solution reaches it with the
whole arm collision-free, and the start joints are collision-free too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from clamgen.robot import ur5
from clamgen.robot.kinematics import solve_tip_position
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles, Scene

# Reach (no obstacles): target box, and speeds of the paper's Table 1 (m/s).
REACH_BOX_LOW_M = np.array([0.4, -0.2, 0.0])
REACH_BOX_HIGH_M = np.array([0.8, 0.2, 0.4])
TARGET_SPEEDS_MPS = (0.0, 0.05, 0.1, 0.2)
# "variable" switches among the moving speeds (the paper's "[5-20]" row) ...
VARIABLE_SPEEDS_MPS = (0.05, 0.1, 0.2)
# ... at a random step with this probability per step (mean 1 s between switches at 20 Hz).
SPEED_SWITCH_PROBABILITY = 0.05

# Reach with obstacles (paper: obstacle centres, goal box).
OBSTACLE_CENTER_LOW_M = np.array([0.35, -0.15, 0.05])
OBSTACLE_CENTER_HIGH_M = np.array([0.65, 0.15, 0.2])
OBSTACLE_SIZE_RANGE_M = (0.06, 0.09)  # full side / diameter / height
GOAL_BOX_LOW_M = np.array([0.3, -0.2, 0.15])
GOAL_BOX_HIGH_M = np.array([0.7, 0.2, 0.35])

# The arm starts with its tip at a random point of the task's box, in the IK branch nearest the
# home pose (elbow up, tool down), so starts look like a real cell's, and at least this far
# from the goal so that no episode starts solved.
MIN_START_GOAL_DISTANCE_M = 0.1
MAX_SAMPLING_ATTEMPTS = 1000

SpeedSpec = float | str  # a speed in m/s, or "variable"


@dataclass(frozen=True)
class Task:
    """One episode's setup. Positions in the world (= DH base) frame, metres.

    start_joints: (6,) radians. target_position_m: (3,). target_velocity_mps: (3,).
    speed: the task's speed setting, a float (m/s) or "variable".
    """

    start_joints: np.ndarray
    target_position_m: np.ndarray
    target_velocity_mps: np.ndarray
    obstacles: Obstacles = field(default_factory=Obstacles.empty)
    speed: SpeedSpec = 0.0

    def __post_init__(self) -> None:
        # Checked here, where a task is made, so that a bad one fails in one line naming the
        # field instead of deep inside the simulator or the planner.
        joints = _finite_vector("start_joints", self.start_joints, ur5.NUM_JOINTS)
        low, high = ur5.JOINT_LIMITS.T
        if np.any(joints < low - JOINT_LIMIT_TOLERANCE_RAD) or np.any(
            joints > high + JOINT_LIMIT_TOLERANCE_RAD
        ):
            raise ValueError(
                "Task.start_joints must lie within the joint limits, |q| <= "
                f"{np.round(high, 4).tolist()} rad, got {joints.tolist()}"
            )
        target = _finite_vector("target_position_m", self.target_position_m, 3)
        velocity = _finite_vector("target_velocity_mps", self.target_velocity_mps, 3)
        if not isinstance(self.obstacles, Obstacles):
            raise ValueError(
                "Task.obstacles must be a clamgen.sim.scene.Obstacles (Obstacles.empty() for "
                f"none), got {self.obstacles!r}"
            )
        _check_obstacles(self.obstacles)
        try:
            speed = validate_speed(self.speed)
        except (TypeError, ValueError) as error:
            raise ValueError(f"Task.speed: {error}") from None
        object.__setattr__(self, "start_joints", joints)
        object.__setattr__(self, "target_position_m", target)
        object.__setattr__(self, "target_velocity_mps", velocity)
        object.__setattr__(self, "speed", speed)


# Start joints may exceed the limits by this much (float32 round trips of joints at a limit).
JOINT_LIMIT_TOLERANCE_RAD = 1e-6


def _finite_vector(name: str, value: object, size: int) -> np.ndarray:
    """`value` as a float64 array (size,), or a ValueError naming `Task.<name>`."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (size,) or not np.all(np.isfinite(array)):
        shown = value if array is None else array.tolist()
        raise ValueError(f"Task.{name} must be {size} finite numbers, got {shown!r}")
    return array


def _check_obstacles(obstacles: Obstacles) -> None:
    """A ValueError unless the obstacle arrays agree in length, hold finite positions and
    positive finite half sizes, and name known kinds, at most `C.MAX_OBSTACLES` of them."""
    kinds = np.asarray(obstacles.kinds)
    num = len(kinds)
    if kinds.ndim != 1 or num > C.MAX_OBSTACLES:
        raise ValueError(
            f"Task.obstacles must hold at most {C.MAX_OBSTACLES} obstacles (kinds of shape "
            f"(N,)), got kinds of shape {kinds.shape}"
        )
    if not np.isin(kinds, (C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER)).all():
        raise ValueError(
            f"Task.obstacles.kinds must be OBSTACLE_BOX ({C.OBSTACLE_BOX}) or OBSTACLE_CYLINDER "
            f"({C.OBSTACLE_CYLINDER}), got {kinds.tolist()}"
        )
    for name in ("positions_m", "half_sizes_m"):
        array = np.asarray(getattr(obstacles, name), dtype=np.float64)
        if array.shape != (num, 3) or not np.all(np.isfinite(array)):
            raise ValueError(
                f"Task.obstacles.{name} must be ({num}, 3) finite numbers, got {array.tolist()}"
            )
    if np.any(np.asarray(obstacles.half_sizes_m) <= 0):
        raise ValueError(
            f"Task.obstacles.half_sizes_m must be > 0, got {np.asarray(obstacles.half_sizes_m)}"
        )


def validate_speed(speed: SpeedSpec) -> SpeedSpec:
    """A non-negative finite speed in m/s, or "variable"; anything else is a ValueError."""
    if isinstance(speed, str):
        if speed != "variable":
            raise ValueError(f"target speed must be a number (m/s) or 'variable', got {speed!r}")
        return speed
    if isinstance(speed, bool) or not isinstance(speed, int | float | np.integer | np.floating):
        raise ValueError(f"target speed must be a number (m/s) or 'variable', got {speed!r}")
    speed = float(speed)
    if not np.isfinite(speed) or speed < 0:
        raise ValueError(f"target speed must be finite and >= 0 m/s, got {speed}")
    return speed


def random_direction(rng: np.random.Generator) -> np.ndarray:
    """A unit vector uniform on the sphere, (3,)."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def initial_velocity(rng: np.random.Generator, speed: SpeedSpec) -> np.ndarray:
    magnitude = rng.choice(VARIABLE_SPEEDS_MPS) if speed == "variable" else speed
    return random_direction(rng) * magnitude


def move_target(
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    dt_s: float,
    speed: SpeedSpec,
    rng: np.random.Generator,
    low_m: np.ndarray = REACH_BOX_LOW_M,
    high_m: np.ndarray = REACH_BOX_HIGH_M,
) -> tuple[np.ndarray, np.ndarray]:
    """Advance a target by one control step: straight motion, mirror reflection at the faces.

    With speed "variable" the speed switches at random (keeping the direction).
    Returns (new position (3,), new velocity (3,)).
    """
    if speed == "variable" and rng.random() < SPEED_SWITCH_PROBABILITY:
        norm = np.linalg.norm(velocity_mps)
        direction = velocity_mps / norm if norm > 0 else random_direction(rng)
        velocity_mps = direction * rng.choice(VARIABLE_SPEEDS_MPS)
    position = position_m + velocity_mps * dt_s
    velocity = velocity_mps.copy()
    below, above = position < low_m, position > high_m
    position = np.where(below, 2 * low_m - position, position)
    position = np.where(above, 2 * high_m - position, position)
    velocity[below | above] *= -1
    return position, velocity


def sample_start_joints(
    rng: np.random.Generator,
    scene: Scene,
    low_m: np.ndarray,
    high_m: np.ndarray,
    avoid_point_m: np.ndarray | None = None,
) -> np.ndarray:
    """Collision-free start joints with the tip at a random point of the box [low, high]."""
    for _ in range(MAX_SAMPLING_ATTEMPTS):
        point = rng.uniform(low_m, high_m)
        if avoid_point_m is not None:
            if np.linalg.norm(point - avoid_point_m) < MIN_START_GOAL_DISTANCE_M:
                continue
        for joints in solve_tip_position(point, reference_joints=ur5.HOME_JOINTS):
            if not scene.in_collision(joints):
                return joints
    raise RuntimeError("could not sample collision-free start joints")


def sample_reach_task(rng: np.random.Generator, scene: Scene, speed: SpeedSpec = 0.0) -> Task:
    """A reach task without obstacles; `scene` is used for the collision check of the start."""
    speed = validate_speed(speed)
    scene.set_obstacles(Obstacles.empty())
    target = rng.uniform(REACH_BOX_LOW_M, REACH_BOX_HIGH_M)
    start = sample_start_joints(rng, scene, REACH_BOX_LOW_M, REACH_BOX_HIGH_M, target)
    return Task(start, target, initial_velocity(rng, speed), Obstacles.empty(), speed)


def sample_obstacles(rng: np.random.Generator, num_obstacles: int) -> Obstacles:
    """`num_obstacles` boxes or cylinders with centres in the obstacle region."""
    kinds = rng.integers(0, 2, size=num_obstacles)
    positions = rng.uniform(OBSTACLE_CENTER_LOW_M, OBSTACLE_CENTER_HIGH_M, (num_obstacles, 3))
    full = rng.uniform(*OBSTACLE_SIZE_RANGE_M, size=(num_obstacles, 3))
    # A cylinder has one diameter (both horizontal half sizes equal its radius).
    full[:, 1] = np.where(kinds == C.OBSTACLE_CYLINDER, full[:, 0], full[:, 1])
    return Obstacles(kinds.astype(np.int64), positions, full / 2)


def collision_free_solutions(scene: Scene, point_m: np.ndarray) -> np.ndarray:
    """All IK solutions (n, 6) putting the tip at `point_m` with the whole arm collision-free."""
    solutions = solve_tip_position(point_m, reference_joints=ur5.HOME_JOINTS)
    if len(solutions) == 0:
        return solutions
    return solutions[~scene.collision_mask(solutions)]


def sample_obstacle_task(
    rng: np.random.Generator, scene: Scene, num_obstacles: int = 2, speed: SpeedSpec = 0.0
) -> Task:
    """A reach task with obstacles: reachable collision-free goal, collision-free start.

    Leaves the obstacles placed in `scene`.
    """
    speed = validate_speed(speed)
    for _ in range(MAX_SAMPLING_ATTEMPTS):
        obstacles = sample_obstacles(rng, num_obstacles)
        scene.set_obstacles(obstacles)
        for _ in range(20):
            goal = rng.uniform(GOAL_BOX_LOW_M, GOAL_BOX_HIGH_M)
            if len(collision_free_solutions(scene, goal)) == 0:
                continue
            start = sample_start_joints(rng, scene, GOAL_BOX_LOW_M, GOAL_BOX_HIGH_M, goal)
            return Task(start, goal, initial_velocity(rng, speed), obstacles, speed)
    raise RuntimeError("could not sample a reachable obstacle task")
