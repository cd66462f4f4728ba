"""Reach past a blocked path (ours, beyond the paper): obstacle tasks that need avoidance.

The paper's obstacle tasks (`clamgen.tasks.reach.sample_obstacle_task`) mostly leave the way
free: obstacle-blind IK interpolation succeeds on about 90% of them. Here every task blocks the
obstacle-blind motion. Same robot, cameras, obstacle shapes, size ranges and centre region, goal
box, start rule and options as the obstacle tasks; sampled without rolling anything out:

1. A goal uniform in the goal box and start joints by the obstacle tasks' start rule (tip
   uniform in the goal box, IK branch nearest home, at least `MIN_START_GOAL_DISTANCE_M` from
   the goal, collision-free).
2. The blind path: the straight joint-space segment from the start to the goal's IK solution
   nearest the start, which is what `IKInterpolationPolicy` follows (it steps towards that
   solution at the joint-speed limit, and stepping towards it keeps it the nearest), sampled at
   the env's collision-check resolution. It must be free of the table, so that an obstacle is
   what blocks it, and must not pass within the success distance of the goal early.
3. A blocker: an obstacle of random shape and size whose centre is a random point of the arm's
   collision geometry at a random configuration of the blind path (within the first
   `MAX_EPISODE_STEPS` steps and `BLOCKER_PATH_FRACTION` of the way), moved by up to its half
   size and clipped into the obstacle centre region; kept only if the arm there touches it.
4. The other obstacles, sampled as in the obstacle tasks; the blocker takes a random slot.
5. Accepted when the start is collision-free and the goal has a collision-free IK solution.

So the blind motion provably collides (some configuration it passes through, before it could
succeed, touches the blocker), and the goal and start are valid by construction. That RRT with
the full model then finds a path is measured, not enforced (`results/blocked/`), because
planning costs more than a whole reset.

With a moving target (`target_speed` > 0) the blocking holds for the target's initial position.
"""

from __future__ import annotations

import numpy as np

from clamgen.robot.kinematics import solve_tip_position, tip_position
from clamgen.sim.scene import Obstacles, Scene
from clamgen.tasks.reach import (
    GOAL_BOX_HIGH_M,
    GOAL_BOX_LOW_M,
    MAX_SAMPLING_ATTEMPTS,
    OBSTACLE_CENTER_HIGH_M,
    OBSTACLE_CENTER_LOW_M,
    SpeedSpec,
    Task,
    initial_velocity,
    sample_obstacles,
    sample_start_joints,
    validate_speed,
)

# Same numbers as `clamgen.envs.reach_env` (imported from there it would be a cycle: the env
# imports the tasks); `tests/tasks/test_blocked.py` checks that they agree.
MAX_JOINT_DELTA_RAD = 0.05
COLLISION_CHECK_RESOLUTION_RAD = 0.01
SUCCESS_DISTANCE_M = 0.02
MAX_EPISODE_STEPS = 100

# The blocker sits on this fraction of the blind path (not at the very start, where it would
# touch the start configuration, nor at the goal, which must stay reachable).
BLOCKER_PATH_FRACTION = (0.1, 0.9)
# The blind path must stay this far from the goal before the blocker: the episode would succeed
# (and end) before the collision otherwise. Success distance plus a margin.
MIN_GOAL_CLEARANCE_BEFORE_BLOCK_M = SUCCESS_DISTANCE_M + 0.02
# Blocker placements tried per (start, goal) pair, and candidate arm points drawn per try.
BLOCKER_ATTEMPTS = 10
ARM_POINTS_PER_ATTEMPT = 16
# Other obstacles drawn per blocker before drawing a new blocker.
OTHER_OBSTACLE_ATTEMPTS = 5
_REGION = (OBSTACLE_CENTER_LOW_M, OBSTACLE_CENTER_HIGH_M)


def blind_goal_joints(start_joints: np.ndarray, goal_m: np.ndarray) -> np.ndarray | None:
    """The goal's IK solution (6,) nearest `start_joints`: where IK interpolation heads; None
    if the goal is unreachable. Same rule as `IKInterpolationPolicy.target_joints`."""
    solutions = solve_tip_position(goal_m, reference_joints=start_joints)
    return solutions[0] if len(solutions) else None


def blind_path(
    start_joints: np.ndarray,
    goal_joints: np.ndarray,
    resolution_rad: float = COLLISION_CHECK_RESOLUTION_RAD,
) -> np.ndarray:
    """Configurations (n, 6) on the straight joint-space segment start -> goal, `resolution_rad`
    apart on the joint that moves most (both ends included)."""
    delta = goal_joints - start_joints
    num = max(1, int(np.ceil(np.max(np.abs(delta)) / resolution_rad)))
    return start_joints + np.linspace(0.0, 1.0, num + 1)[:, None] * delta


def blockable_indices(path: np.ndarray, goal_m: np.ndarray) -> np.ndarray:
    """Indices of `path` (from `blind_path`) where a blocker makes IK interpolation fail: within
    `BLOCKER_PATH_FRACTION` of the way, reached within `MAX_EPISODE_STEPS` steps, and with the
    tip never within `MIN_GOAL_CLEARANCE_BEFORE_BLOCK_M` of the goal up to there."""
    n = len(path) - 1
    fraction = np.arange(n + 1) / n
    travelled_rad = fraction * np.max(np.abs(path[-1] - path[0]))
    steps = np.ceil(travelled_rad / MAX_JOINT_DELTA_RAD - 1e-9)
    clearance = np.linalg.norm(tip_position(path) - goal_m, axis=-1)
    clear_so_far = np.minimum.accumulate(clearance) > MIN_GOAL_CLEARANCE_BEFORE_BLOCK_M
    ok = (
        (fraction >= BLOCKER_PATH_FRACTION[0])
        & (fraction <= BLOCKER_PATH_FRACTION[1])
        & (steps <= MAX_EPISODE_STEPS)
        & clear_so_far
    )
    return np.flatnonzero(ok)


def arm_points(scene: Scene, joints: np.ndarray, rng: np.random.Generator, num: int) -> np.ndarray:
    """`num` random points (num, 3) on the axes of the arm's collision geoms (capsules and
    cylinders) at `joints`, world frame; each geom equally likely. Leaves the arm there."""
    scene.set_joints(joints)
    geoms = rng.choice(scene.robot_geoms, size=num)
    centres = scene.data.geom_xpos[geoms]
    axes = scene.data.geom_xmat[geoms].reshape(num, 3, 3)[:, :, 2]
    half_lengths = scene.model.geom_size[geoms, 1]
    return centres + rng.uniform(-1.0, 1.0, (num, 1)) * half_lengths[:, None] * axes


def sample_blocker(
    rng: np.random.Generator, scene: Scene, path: np.ndarray, candidates: np.ndarray
) -> tuple[Obstacles, int] | None:
    """One obstacle touching the arm somewhere on `path` at an index among `candidates` but not
    at its start, with its centre in the obstacle region; (obstacle, path index) or None after
    `BLOCKER_ATTEMPTS` tries. Leaves the obstacle placed in `scene`."""
    for _ in range(BLOCKER_ATTEMPTS):
        index = int(rng.choice(candidates))
        obstacle = sample_obstacles(rng, 1)
        points = arm_points(scene, path[index], rng, ARM_POINTS_PER_ATTEMPT)
        half = obstacle.half_sizes_m[0]
        centres = points + rng.uniform(-half, half, points.shape)
        inside = np.all((centres >= _REGION[0]) & (centres <= _REGION[1]), axis=1)
        if not inside.any():
            # No point of the arm near the region here: clip the nearest one into it.
            nearest = np.argmin(np.linalg.norm(centres - np.clip(centres, *_REGION), axis=1))
            centre = np.clip(centres[nearest], *_REGION)
        else:
            centre = centres[rng.choice(np.flatnonzero(inside))]
        blocker = Obstacles(obstacle.kinds, centre[None], obstacle.half_sizes_m)
        scene.set_obstacles(blocker)
        if scene.in_collision(path[index]) and not scene.in_collision(path[0]):
            return blocker, index
    return None


def _combine(rng: np.random.Generator, blocker: Obstacles, others: Obstacles) -> Obstacles:
    """Blocker and others in one set, the blocker in a random slot."""
    kinds = np.concatenate([blocker.kinds, others.kinds])
    positions = np.concatenate([blocker.positions_m, others.positions_m])
    half_sizes = np.concatenate([blocker.half_sizes_m, others.half_sizes_m])
    order = rng.permutation(len(kinds))
    return Obstacles(kinds[order], positions[order], half_sizes[order])


def sample_blocked_task(
    rng: np.random.Generator, scene: Scene, num_obstacles: int = 2, speed: SpeedSpec = 0.0
) -> Task:
    """A task whose obstacle-blind IK-interpolation motion collides, with a collision-free
    start and a goal reachable by a collision-free IK solution (see the module docstring).

    Leaves the obstacles placed in `scene`.
    """
    speed = validate_speed(speed)
    if num_obstacles < 1:
        raise ValueError(f"a blocked task needs num_obstacles >= 1, got {num_obstacles}")
    for _ in range(MAX_SAMPLING_ATTEMPTS):
        scene.set_obstacles(Obstacles.empty())
        goal = rng.uniform(GOAL_BOX_LOW_M, GOAL_BOX_HIGH_M)
        start = sample_start_joints(rng, scene, GOAL_BOX_LOW_M, GOAL_BOX_HIGH_M, goal)
        # Every IK solution of the goal, nearest the start first: the first is where IK
        # interpolation heads, all of them are the candidates for a collision-free goal.
        goal_solutions = solve_tip_position(goal, reference_joints=start)
        if len(goal_solutions) == 0:
            continue
        path = blind_path(start, goal_solutions[0])
        candidates = blockable_indices(path, goal)
        # Only an obstacle may block the blind motion, not the table.
        if len(candidates) == 0 or scene.collision_mask(path).any():
            continue
        placed = sample_blocker(rng, scene, path, candidates)
        if placed is None:
            continue
        blocker, _ = placed
        for _ in range(OTHER_OBSTACLE_ATTEMPTS):
            obstacles = _combine(rng, blocker, sample_obstacles(rng, num_obstacles - 1))
            scene.set_obstacles(obstacles)
            if scene.in_collision(start):
                continue
            if not scene.collision_mask(goal_solutions).all():
                return Task(start, goal, initial_velocity(rng, speed), obstacles, speed)
    raise RuntimeError("could not sample a blocked obstacle task")
