"""RRT baseline with the full scene model (paper, Table "obstacle avoidance, static target").

Unlike the learned policies, this baseline knows the exact obstacles. At the start of each
episode it plans once, open loop, with OMPL's RRTConnect in joint space, using a private copy
of the MuJoCo scene as the collision checker, and then follows the planned path at the same
joint-speed limit as every other policy (`MAX_JOINT_DELTA_RAD` per step).

Planning, step by step (`RRTPolicy.reset`):
1. Goal configurations: the collision-free IK solutions of the goal point
   (`clamgen.tasks.reach.collision_free_solutions`), moved to the 2 pi copy nearest the start and
   sorted by max-abs joint distance to it (`RRTConfig.goal_choice`).
2. For each candidate (nearest first, up to `max_goal_candidates`, sharing the time budget):
   RRTConnect in a `RealVectorStateSpace(6)` bounded by the joint limits (optionally narrowed
   around start and goal), MuJoCo as the state validity checker; edges are checked at most
   `check_resolution_rad` apart on every joint. Only an *exact* solution counts: OMPL 2's
   RRTConnect reports the closest approximate path on timeout and its status is then truthy.
3. The path is shortcut / smoothed (`og.PathSimplifier`), re-checked by OMPL, interpolated so
   that consecutive waypoints are at most `MAX_JOINT_DELTA_RAD` apart (max-abs) and re-checked
   once more, independently of OMPL, at the finer `validation_resolution_rad`.

The target is assumed static (the paper evaluates RRT on static targets only): the plan goes to
the target's position at reset.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from clamgen.envs.reach_env import MAX_JOINT_DELTA_RAD
from clamgen.robot import ur5
from clamgen.robot.kinematics import wrap_joints
from clamgen.sim.scene import Scene
from clamgen.tasks.reach import collision_free_solutions

# `act` moves on to the next waypoint once the joints are this close (max-abs, radians) to the
# current one. Observations are float32 (~5e-7 rad resolution at |q| ~ 2 pi), so reaching a
# waypoint leaves a much smaller error than this.
WAYPOINT_REACHED_TOL_RAD = 1e-4

JointValidity = Callable[[np.ndarray], bool]


@dataclass(frozen=True)
class RRTConfig:
    """Settings of the RRT baseline."""

    time_limit_s: float = 2.0
    """Wall-clock budget of OMPL's RRTConnect per episode, seconds, shared by all goal candidates
    (each gets the remaining budget divided by the number of candidates left)."""
    check_resolution_rad: float = 0.01
    """Largest change of any joint between consecutive validity checks along an edge, radians.
    Same as the env's `COLLISION_CHECK_RESOLUTION_RAD`: no point of the arm moves more than a few
    cm between checks, less than an obstacle's size."""
    validation_resolution_rad: float = 0.002
    """The final (interpolated) path is re-checked with this step on every joint, radians."""
    simplify: bool = True
    """Shortcut and smooth the raw RRTConnect path (`og.PathSimplifier.simplify`)."""
    simplify_time_s: float = 0.2
    """Time limit of the simplification, seconds (it usually converges well before)."""
    goal_choice: Literal["nearest_start", "nearest_home"] = "nearest_start"
    """Order of the goal IK candidates: max-abs joint distance to the start joints, or to
    `ur5.HOME_JOINTS` (the order of `collision_free_solutions`)."""
    max_goal_candidates: int = 4
    """How many goal IK solutions to try, in the order above, before reporting failure."""
    joint_window_rad: float | None = math.pi
    """Narrow each joint's planning bounds to [min(start, goal) - w, max(start, goal) + w]
    (kept at least 2 pi wide and inside the joint limits), radians. Every pose of the arm still
    has a representative inside, but RRT samples a 2^5 times smaller volume than with the
    +-2 pi limits and cannot wander a full turn away. None: plan within the full joint limits."""
    range_rad: float | None = None
    """RRTConnect's maximum extension per step (L2 in joint space, radians); None: OMPL's default,
    0.2 x the space's maximum extent."""
    max_checks: int | None = None
    """When set, RRTConnect stops after this many validity checks instead of at
    `time_limit_s`. With `seed` (and `simplify_max_checks`), a plan then does not depend on
    the machine's speed or load."""
    simplify_max_checks: int | None = None
    """When set, the simplification stops after this many validity checks instead of at
    `simplify_time_s` (it makes one full round at least, as with the time limit)."""
    seed: int | None = 1
    """Seed of OMPL's random number generators, re-applied before every plan so that a task's
    plan does not depend on the episodes before it (>= 1: OMPL ignores 0). None: not seeded.
    Plans that hit a time limit still depend on the machine's speed (not with `max_checks`)."""
    quiet: bool = True
    """Raise OMPL's log level to warnings (the wheel logs debug messages by default)."""

    def __post_init__(self) -> None:
        positive = {
            "time_limit_s": self.time_limit_s,
            "check_resolution_rad": self.check_resolution_rad,
            "validation_resolution_rad": self.validation_resolution_rad,
            "simplify_time_s": self.simplify_time_s,
        }
        for name, value in positive.items():
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if self.goal_choice not in ("nearest_start", "nearest_home"):
            raise ValueError(f"unknown goal_choice {self.goal_choice!r}")
        if self.max_goal_candidates < 1:
            raise ValueError(f"max_goal_candidates must be >= 1, got {self.max_goal_candidates}")
        if self.joint_window_rad is not None and not self.joint_window_rad > 0:
            raise ValueError(f"joint_window_rad must be > 0 or None, got {self.joint_window_rad}")
        if self.range_rad is not None and not self.range_rad > 0:
            raise ValueError(f"range_rad must be > 0 or None, got {self.range_rad}")
        for name in ("max_checks", "simplify_max_checks"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")
        if self.seed is not None and self.seed < 1:
            raise ValueError(f"seed must be >= 1 (OMPL ignores 0) or None, got {self.seed}")


@dataclass(frozen=True)
class PlanResult:
    """Outcome of one `plan_joint_path` call.

    waypoints: (n, 6) radians from start to goal, consecutive rows at most
        `MAX_JOINT_DELTA_RAD` apart (max-abs), or None on failure.
    status: OMPL's planner status ("Exact solution", "Approximate solution", "Timeout",
        "Invalid goal", ...), or "Invalid path" when the final re-check found a collision.
    solve_time_s: wall-clock seconds spent in RRTConnect's `solve`.
    """

    waypoints: np.ndarray | None
    status: str
    solve_time_s: float

    @property
    def succeeded(self) -> bool:
        return self.waypoints is not None


def _ompl() -> tuple[Any, Any, Any]:
    """OMPL's base, geometric and util modules, imported on first use (an optional dependency)."""
    try:
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ImportError(
            "the RRT baseline needs OMPL 2 (`pip install ompl`, or clamgen[planning])"
        ) from error
    return ob, og, ou


def planning_bounds(
    start: np.ndarray, goal: np.ndarray, window_rad: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint planning bounds (low (6,), high (6,)), radians.

    The joint limits, or with `window_rad` the interval [min(start, goal) - w,
    max(start, goal) + w], shifted inwards where it crosses a limit (so it stays at least
    min(2 w, limit range) wide) and clipped to the limits.
    """
    lo_limit, hi_limit = ur5.JOINT_LIMITS[:, 0], ur5.JOINT_LIMITS[:, 1]
    if window_rad is None:
        return lo_limit.copy(), hi_limit.copy()
    low = np.minimum(start, goal) - window_rad
    high = np.maximum(start, goal) + window_rad
    # Keep the width where a limit cuts the window: move the cut part to the other side.
    high = high + np.maximum(lo_limit - low, 0.0)
    low = low - np.maximum(high - hi_limit, 0.0)
    return np.maximum(low, lo_limit), np.minimum(high, hi_limit)


def validity_resolution_fraction(check_resolution_rad: float, max_extent_rad: float) -> float:
    """OMPL's state validity checking resolution for checks <= `check_resolution_rad` apart.

    OMPL's `DiscreteMotionValidator` splits an edge of L2 length d into
    ceil(d / (fraction * max_extent)) equal pieces, so consecutive checks are at most
    fraction * max_extent apart in L2, and no joint (max-abs <= L2) changes by more than
    `check_resolution_rad` between checks when

        fraction = check_resolution_rad / max_extent,

    where max_extent is the L2 diagonal of the bounds box (`StateSpace.getMaximumExtent`).
    """
    return check_resolution_rad / max_extent_rad


def interpolate_path(states: np.ndarray, max_step_rad: float = MAX_JOINT_DELTA_RAD) -> np.ndarray:
    """Densify a joint path (k, 6) so consecutive rows are at most `max_step_rad` apart (max-abs).

    Every input state is kept; each segment is split into equal pieces (straight in joint space).
    """
    dense = [states[:1]]
    for a, b in itertools.pairwise(states):
        num = max(1, math.ceil(float(np.max(np.abs(b - a))) / max_step_rad))
        fractions = np.arange(1, num + 1)[:, None] / num
        dense.append(a + fractions * (b - a))
    return np.concatenate(dense, axis=0)


def path_is_valid(is_valid: JointValidity, path: np.ndarray, resolution_rad: float) -> bool:
    """Whether every configuration on the straight segments of `path` (n, 6) is valid, checked
    at steps of at most `resolution_rad` on every joint (endpoints included)."""
    if not is_valid(path[0]):
        return False
    for a, b in itertools.pairwise(path):
        num = max(1, math.ceil(float(np.max(np.abs(b - a))) / resolution_rad))
        for k in range(1, num + 1):
            if not is_valid(a + (k / num) * (b - a)):
                return False
    return True


def path_length_rad(path: np.ndarray) -> float:
    """Sum over segments of the max-abs joint change, radians: at the shared joint-speed limit
    the path takes at least this / `MAX_JOINT_DELTA_RAD` steps."""
    return float(np.sum(np.max(np.abs(np.diff(path, axis=0)), axis=1))) if len(path) > 1 else 0.0


def _seed_ompl(ou: Any, seed: int) -> None:
    # `RNG.setSeed` re-seeds the generator that seeds every RNG created afterwards (samplers,
    # the simplifier), which is all a new planner needs; after the first RNG exists it also logs
    # an error ("will not lead to deterministic sampling", about the RNGs already alive), so
    # silence the log for the call.
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(seed)
    finally:
        ou.setLogLevel(level)


def plan_joint_path(
    is_valid: JointValidity,
    start: np.ndarray,
    goal: np.ndarray,
    config: RRTConfig = RRTConfig(),
    time_limit_s: float | None = None,
    max_checks: int | None = None,
) -> PlanResult:
    """Plan a collision-free joint path from `start` to `goal` with OMPL's RRTConnect.

    Args:
        is_valid: maps joints (6,) radians to True when the arm there is collision-free. Called
            from inside OMPL: it must not raise.
        start, goal: (6,) joint configurations, radians.
        config: resolutions, simplification, bounds and seed (see `RRTConfig`).
        time_limit_s: RRTConnect's time limit, seconds (default `config.time_limit_s`).
        max_checks: RRTConnect's budget of validity checks instead (default
            `config.max_checks`; None: the time limit).

    Returns:
        A `PlanResult`; only an exact solution that passes the final fine re-check succeeds.
    """
    ob, og, ou = _ompl()
    if config.quiet and ou.getLogLevel().value < ou.LOG_WARN.value:
        ou.setLogLevel(ou.LOG_WARN)
    if config.seed is not None:
        _seed_ompl(ou, config.seed)
    start = np.asarray(start, np.float64)
    goal = np.asarray(goal, np.float64)
    time_limit_s = config.time_limit_s if time_limit_s is None else time_limit_s
    # RRTConnect would spend its whole time limit waiting for a valid goal state (and report
    # "Invalid goal" only then): fail at once, with OMPL's words.
    if not is_valid(start):
        return PlanResult(None, "Invalid start", 0.0)
    if not is_valid(goal):
        return PlanResult(None, "Invalid goal", 0.0)

    space = ob.RealVectorStateSpace(ur5.NUM_JOINTS)
    low, high = planning_bounds(start, goal, config.joint_window_rad)
    bounds = ob.RealVectorBounds(ur5.NUM_JOINTS)
    for i in range(ur5.NUM_JOINTS):
        bounds.setLow(i, float(low[i]))
        bounds.setHigh(i, float(high[i]))
    space.setBounds(bounds)

    si = ob.SpaceInformation(space)
    # OMPL 2 (nanobind) takes a plain Python callable; states index like sequences.
    checks = [0]  # validity checks so far, for the budgets in checks

    def counted(state) -> bool:
        checks[0] += 1
        return bool(is_valid(np.array(state[0:6])))

    si.setStateValidityChecker(counted)
    si.setStateValidityCheckingResolution(
        validity_resolution_fraction(config.check_resolution_rad, space.getMaximumExtent())
    )
    si.setup()

    start_state, goal_state = si.allocState(), si.allocState()
    start_state[0:6] = start.tolist()
    goal_state[0:6] = goal.tolist()
    pdef = ob.ProblemDefinition(si)
    pdef.setStartAndGoalStates(start_state, goal_state)
    planner = og.RRTConnect(si)
    if config.range_rad is not None:
        planner.setRange(config.range_rad)
    planner.setProblemDefinition(pdef)
    planner.setup()

    tic = time.perf_counter()
    max_checks = config.max_checks if max_checks is None else max_checks
    if max_checks is None:
        # A plain timed condition: `solve(seconds)` adds a watchdog thread for limits >= 1 s.
        condition = ob.timedPlannerTerminationCondition(max(time_limit_s, 0.0))
    else:
        condition = _checks_condition(ob, checks, max_checks)
    status = planner.solve(condition)
    solve_time_s = time.perf_counter() - tic
    status_name = status.asString()
    # bool(status) is also True for APPROXIMATE_SOLUTION, which RRTConnect reports on timeout
    # (the path then ends short of the goal): require an exact solution.
    if status.getStatus() != ob.PlannerStatus.EXACT_SOLUTION or not pdef.hasExactSolution():
        return PlanResult(None, status_name, solve_time_s)

    path = pdef.getSolutionPath()
    if config.simplify:
        limit = config.simplify_time_s
        if config.simplify_max_checks is not None:
            limit = _checks_condition(ob, checks, config.simplify_max_checks)
        og.PathSimplifier(si).simplify(path, limit)
    states = np.array([path.getState(i)[0:6] for i in range(path.getStateCount())])
    # The simplifier checks its own edits; check the result once more with OMPL's validator,
    # then independently and more finely along the path the policy will actually execute.
    waypoints = interpolate_path(states)
    if (
        not path.check()
        or not np.allclose(states[0], start)
        or not np.allclose(states[-1], goal)
        or not path_is_valid(is_valid, waypoints, config.validation_resolution_rad)
    ):
        return PlanResult(None, "Invalid path", solve_time_s)
    return PlanResult(waypoints, status_name, solve_time_s)


def _checks_condition(ob: Any, checks: list[int], budget: int) -> Any:
    """A termination condition that holds once `budget` more validity checks are counted in
    `checks[0]` (OMPL asks it between its iterations)."""
    limit = checks[0] + max(int(budget), 0)
    return ob.PlannerTerminationCondition(lambda: checks[0] >= limit)


def goal_candidates(
    scene: Scene, start: np.ndarray, point_m: np.ndarray, config: RRTConfig = RRTConfig()
) -> np.ndarray:
    """Collision-free IK solutions (n, 6) putting the tip at `point_m` (world frame, metres),
    as the 2 pi copies nearest `start`, ordered by `config.goal_choice`, at most
    `config.max_goal_candidates` of them. `scene` must hold the task's obstacles."""
    solutions = collision_free_solutions(scene, np.asarray(point_m, np.float64))
    if len(solutions) == 0:
        return solutions
    # Joint angles a full turn apart are the same pose: plan to the copy nearest the start.
    solutions = wrap_joints(solutions, start)
    if config.goal_choice == "nearest_start":
        distance = np.max(np.abs(solutions - start), axis=1)
        solutions = solutions[np.argsort(distance, kind="stable")]
    return solutions[: config.max_goal_candidates]


class RRTPolicy:
    """Plans with RRTConnect on `reset(env)` and follows the path; a `clamgen.policy.Policy`.

    Needs the env (its task and scene model) at reset and joint observations
    (`obs["observation"]`) at every step. After each reset:

    - `last_plan_succeeded`: whether a collision-free path to the goal was found.
    - `last_plan_time_s`: wall-clock seconds of the whole planning (IK, RRTConnect for every
      goal candidate tried, simplification, interpolation, re-checks).
    - `last_path_length_rad`: sum of max-abs joint changes along the path (nan on failure).
    - `last_plan_status`: OMPL's status of the last attempt, or why planning failed.
    - `waypoints`: (n, 6) radians, consecutive rows <= `MAX_JOINT_DELTA_RAD` apart (max-abs);
      `goal_joints`: (6,) the last one. Both None on failure.

    If planning fails, `act` returns zeros: the arm stays where it is and the episode ends
    unsuccessful (truncated) without any collision, which is how the paper counts an RRT
    failure.
    """

    def __init__(self, config: RRTConfig = RRTConfig()) -> None:
        self.config = config
        self._scene: Scene | None = None
        self.waypoints: np.ndarray | None = None
        self._next_index = 0
        self.last_plan_succeeded = False
        self.last_plan_time_s = float("nan")
        self.last_path_length_rad = float("nan")
        self.last_plan_status = "not planned"

    @property
    def goal_joints(self) -> np.ndarray | None:
        return None if self.waypoints is None else self.waypoints[-1].copy()

    def reset(self, env: Any | None = None) -> None:
        """Plan for the env's current task (call right after `env.reset`)."""
        if env is None:
            raise ValueError("RRTPolicy.reset needs the env: it plans with the full scene model")
        base = env.unwrapped
        task = base.task
        if task is None:
            raise RuntimeError("reset the env before the policy: it has no task yet")
        tic = time.perf_counter()
        scene = self._collision_scene(base.scene.collision_margin_m)
        scene.set_obstacles(task.obstacles)
        start = np.asarray(task.start_joints, np.float64)
        self.waypoints, self.last_plan_status = self._plan(scene, start, task.target_position_m)
        self._next_index = 0
        self.last_plan_succeeded = self.waypoints is not None
        self.last_plan_time_s = time.perf_counter() - tic
        self.last_path_length_rad = (
            path_length_rad(self.waypoints) if self.waypoints is not None else float("nan")
        )

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Joint-delta action (6,) float32 in [-1, 1] towards the next waypoint."""
        if "observation" not in obs:
            raise KeyError("RRTPolicy needs joint observations (obs_mode 'joints' or 'both')")
        if self.waypoints is None:
            return np.zeros(ur5.NUM_JOINTS, np.float32)
        joints = np.asarray(obs["observation"], np.float64)
        last = len(self.waypoints) - 1
        # Advance past waypoints already reached; after the last one keep closing on the goal.
        while (
            self._next_index < last
            and np.max(np.abs(self.waypoints[self._next_index] - joints))
            <= WAYPOINT_REACHED_TOL_RAD
        ):
            self._next_index += 1
        delta = self.waypoints[self._next_index] - joints
        return np.clip(delta / MAX_JOINT_DELTA_RAD, -1.0, 1.0).astype(np.float32)

    # -------------------------------------------------------------------- internals
    def _collision_scene(self, collision_margin_m: float) -> Scene:
        # A scene of our own, so planning never moves the env's arm; rebuilt only when the env's
        # collision margin differs (building one compiles the MJCF, ~tens of ms).
        if self._scene is None or self._scene.collision_margin_m != collision_margin_m:
            self._scene = Scene(collision_margin_m)
        return self._scene

    def _plan(
        self, scene: Scene, start: np.ndarray, goal_point_m: np.ndarray
    ) -> tuple[np.ndarray | None, str]:
        """Try the goal candidates in order within the time budget; (waypoints, status)."""
        candidates = goal_candidates(scene, start, goal_point_m, self.config)
        if len(candidates) == 0:
            return None, "No collision-free goal configuration"

        def is_valid(joints: np.ndarray) -> bool:
            return not scene.in_collision(joints)

        deadline = time.perf_counter() + self.config.time_limit_s
        status = "Timeout"
        for i, goal in enumerate(candidates):
            remaining_s = deadline - time.perf_counter()
            if remaining_s <= 0:
                break
            budget_s = remaining_s / (len(candidates) - i)
            result = plan_joint_path(is_valid, start, goal, self.config, budget_s)
            status = result.status
            if result.succeeded:
                return result.waypoints, status
        return None, status
