"""RRT baseline: collision-free plans, executed successfully, honest failures, time limits."""

import time
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

import clamgen  # noqa: F401  (registers the ids)
from clamgen.baselines import RRTConfig, RRTPolicy
from clamgen.baselines.rrt import (
    goal_candidates,
    interpolate_path,
    path_is_valid,
    path_length_rad,
    plan_joint_path,
    planning_bounds,
    validity_resolution_fraction,
)
from clamgen.envs import MAX_JOINT_DELTA_RAD
from clamgen.policy import Policy
from clamgen.robot import ur5
from clamgen.robot.kinematics import tip_position
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles, Scene
from clamgen.tasks import Task

ob = pytest.importorskip("ompl.base")

SEEDS = (0, 1, 2, 3, 4)
# Finer than the planner's own edge checks (0.01 rad) and its final re-check (0.002 rad
# by default, set coarser in the plans checked below so this check is independent).
RECHECK_RESOLUTION_RAD = 0.002
ENV_ID = "CLAMGen/ReachObstacles-v0"


def obstacle_scene(task: Task) -> Scene:
    scene = Scene()
    scene.set_obstacles(task.obstacles)
    return scene


def run_episode(env, policy, obs) -> tuple[bool, bool, int]:
    """(success, any step collided, number of steps) of one episode from `obs`."""
    collided, num_steps = False, 0
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        collided |= info["collision"]
        num_steps += 1
        if terminated or truncated:
            return info["is_success"], collided, num_steps


# ------------------------------------------------------------------------------ helpers
def test_config_rejects_bad_values():
    with pytest.raises(ValueError):
        RRTConfig(time_limit_s=0.0)
    with pytest.raises(ValueError):
        RRTConfig(check_resolution_rad=-0.01)
    with pytest.raises(ValueError):
        RRTConfig(seed=0)
    with pytest.raises(ValueError):
        RRTConfig(goal_choice="random")  # type: ignore[arg-type]
    assert isinstance(RRTPolicy(), Policy)


def test_interpolate_path_steps_and_keeps_states():
    states = np.array([np.zeros(6), np.full(6, 0.12), [0.12, 0.12, -0.3, 0.12, 0.12, 0.12]])
    dense = interpolate_path(states)
    steps = np.max(np.abs(np.diff(dense, axis=0)), axis=1)
    assert np.all(steps <= MAX_JOINT_DELTA_RAD + 1e-12)
    for state in states:
        assert np.min(np.max(np.abs(dense - state), axis=1)) < 1e-12
    assert path_length_rad(dense) == pytest.approx(0.12 + 0.42)


def test_planning_bounds_stay_inside_limits_and_two_pi_wide():
    start = np.array([6.0, -6.0, 3.0, 0.0, 1.0, -1.0])
    goal = np.array([5.5, -5.0, -3.0, 0.5, 1.0, -1.0])
    low, high = planning_bounds(start, goal, np.pi)
    assert np.all(low >= ur5.JOINT_LIMITS[:, 0]) and np.all(high <= ur5.JOINT_LIMITS[:, 1])
    assert np.all(low <= np.minimum(start, goal)) and np.all(high >= np.maximum(start, goal))
    assert np.all(high - low >= 2 * np.pi - 1e-9)
    low, high = planning_bounds(start, goal, None)
    np.testing.assert_array_equal(np.stack([low, high], 1), ur5.JOINT_LIMITS)


def test_ompl_edge_checks_are_within_resolution():
    """OMPL's motion validator, set with `validity_resolution_fraction`, never checks two
    configurations along an edge more than the resolution apart on any joint."""
    space = ob.RealVectorStateSpace(6)
    bounds = ob.RealVectorBounds(6)
    for i, (lo, hi) in enumerate(ur5.JOINT_LIMITS):
        bounds.setLow(i, lo)
        bounds.setHigh(i, hi)
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    checked = []
    si.setStateValidityChecker(lambda state: checked.append(state[0:6]) is None)
    si.setStateValidityCheckingResolution(
        validity_resolution_fraction(0.01, space.getMaximumExtent())
    )
    si.setup()
    a, b = si.allocState(), si.allocState()
    start, end = np.zeros(6), np.array([2.0, -0.3, 1.0, 0.0, 0.1, 3.0])
    a[0:6], b[0:6] = start.tolist(), end.tolist()
    assert si.checkMotion(a, b)
    along = np.array(checked) @ (end - start) / np.dot(end - start, end - start)
    points = np.array(checked)[np.argsort(along)]
    gaps = np.max(np.abs(np.diff(np.vstack([start, points]), axis=0)), axis=1)
    assert len(points) >= 300  # 3 rad on joint 6 in steps of at most 0.01 rad
    assert gaps.max() <= 0.01 + 1e-9


# ---------------------------------------------------------------- plans on sampled tasks
@pytest.fixture(scope="module")
def planned():
    """(seed, waypoints, task, plan time) for each seeded obstacle task."""
    env = gym.make(ENV_ID)
    # The planner's own final re-check is made coarse here, so the test's re-check is new work.
    policy = RRTPolicy(RRTConfig(validation_resolution_rad=0.01))
    out = []
    for seed in SEEDS:
        env.reset(seed=seed)
        policy.reset(env)
        task = env.unwrapped.task
        # Planning used the policy's own scene: the env's arm has not moved.
        np.testing.assert_array_equal(env.unwrapped.scene.joints, task.start_joints)
        out.append((seed, policy.waypoints, task, policy.last_plan_time_s))
    env.close()
    return out


def test_plans_succeed_and_reach_the_goal(planned):
    for seed, waypoints, task, plan_time_s in planned:
        assert waypoints is not None, f"seed {seed}: planning failed"
        np.testing.assert_allclose(waypoints[0], task.start_joints, atol=1e-12)
        np.testing.assert_allclose(tip_position(waypoints[-1]), task.target_position_m, atol=1e-6)
        steps = np.max(np.abs(np.diff(waypoints, axis=0)), axis=1)
        assert np.all(steps <= MAX_JOINT_DELTA_RAD + 1e-12)
        assert np.all(waypoints >= ur5.JOINT_LIMITS[:, 0])
        assert np.all(waypoints <= ur5.JOINT_LIMITS[:, 1])
        assert 0 < plan_time_s < RRTConfig().time_limit_s + 1.0


def test_plans_are_collision_free_at_a_finer_resolution(planned):
    for seed, waypoints, task, _ in planned:
        scene = obstacle_scene(task)
        valid = path_is_valid(
            lambda q, scene=scene: not scene.in_collision(q), waypoints, RECHECK_RESOLUTION_RAD
        )
        assert valid, f"seed {seed}: the planned path collides"


def test_goal_candidates_are_collision_free_and_nearest_first():
    env = gym.make(ENV_ID)
    env.reset(seed=7)
    task = env.unwrapped.task
    scene = obstacle_scene(task)
    goals = goal_candidates(scene, task.start_joints, task.target_position_m, RRTConfig())
    assert 1 <= len(goals) <= RRTConfig().max_goal_candidates
    assert not scene.collision_mask(goals).any()
    assert np.all(np.linalg.norm(tip_position(goals) - task.target_position_m, axis=1) < 1e-6)
    distance = np.max(np.abs(goals - task.start_joints), axis=1)
    assert np.all(np.diff(distance) >= 0)
    env.close()


def test_policy_executes_plans_without_collision():
    env = gym.make(ENV_ID)
    policy = RRTPolicy()
    for seed in SEEDS:
        obs, _ = env.reset(seed=seed)
        policy.reset(env)
        assert policy.last_plan_succeeded, policy.last_plan_status
        success, collided, num_steps = run_episode(env, policy, obs)
        assert success and not collided, f"seed {seed}: success {success}, collided {collided}"
        # Open loop at full joint speed: the episode lasts about as long as the path.
        assert num_steps <= np.ceil(policy.last_path_length_rad / MAX_JOINT_DELTA_RAD) + 1
    env.close()


def test_same_seed_same_plan():
    env = gym.make(ENV_ID)
    env.reset(seed=11)
    first, second = RRTPolicy(), RRTPolicy()
    first.reset(env)
    second.reset(env)
    np.testing.assert_array_equal(first.waypoints, second.waypoints)
    env.close()


def test_a_budget_in_checks_makes_the_plan_independent_of_the_checks_speed():
    """A joint-space wall between start and goal; the same plan when each check is slow."""
    start, goal = np.zeros(6), np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])

    def wall(q: np.ndarray) -> bool:
        return not (abs(q[0] - 1.0) < 0.2 and abs(q[1]) < 0.8)

    def slow_wall(q: np.ndarray) -> bool:
        end = time.perf_counter() + 2e-5
        while time.perf_counter() < end:
            pass
        return wall(q)

    config = RRTConfig(max_checks=3000, simplify_max_checks=300, joint_window_rad=1.0)
    fast = plan_joint_path(wall, start, goal, config)
    slow = plan_joint_path(slow_wall, start, goal, config)
    assert fast.succeeded and slow.succeeded
    np.testing.assert_array_equal(fast.waypoints, slow.waypoints)
    assert path_is_valid(wall, fast.waypoints, 0.002)
    # Without the simplification (which makes one full round whatever its budget): start and
    # goal, the search (it may finish the iteration it is in when its budget runs out), the
    # final re-checks of the path's states and along it.
    calls = []

    def counted(q: np.ndarray) -> bool:
        calls.append(q)
        return wall(q)

    plain = plan_joint_path(counted, start, goal, replace(config, simplify=False))
    along = path_length_rad(plain.waypoints) / config.validation_resolution_rad
    assert len(calls) <= 2 + 3000 + 500 + 2 * len(plain.waypoints) + along
    # A budget too small to get round the wall fails at once.
    tiny = plan_joint_path(wall, start, goal, RRTConfig(max_checks=5, joint_window_rad=1.0))
    assert not tiny.succeeded and tiny.solve_time_s < 0.5
    with pytest.raises(ValueError):
        RRTConfig(max_checks=0)


# ------------------------------------------------------------------------------- failures
def test_enclosed_goal_fails_and_the_arm_stays():
    """A box around the goal point: no collision-free goal configuration exists."""
    goal = np.array([0.5, 0.0, 0.25])
    obstacles = Obstacles(
        kinds=np.array([C.OBSTACLE_BOX]),
        positions_m=goal[None],
        half_sizes_m=np.full((1, 3), 0.06),
    )
    task = Task(ur5.HOME_JOINTS.copy(), goal, np.zeros(3), obstacles)
    assert not obstacle_scene(task).in_collision(task.start_joints)
    env = gym.make(ENV_ID, max_episode_steps=5)
    obs, _ = env.reset(options={"task": task})
    policy = RRTPolicy()
    policy.reset(env)
    assert not policy.last_plan_succeeded
    assert policy.waypoints is None and np.isnan(policy.last_path_length_rad)
    np.testing.assert_array_equal(policy.act(obs), np.zeros(6))
    success, collided, _ = run_episode(env, policy, obs)
    assert not success and not collided
    np.testing.assert_allclose(env.unwrapped.scene.joints, task.start_joints)
    env.close()


def test_goal_configuration_in_collision_fails():
    env = gym.make(ENV_ID)
    env.reset(seed=5)
    task = env.unwrapped.task
    scene = obstacle_scene(task)
    # A configuration with the tip inside the first obstacle.
    inside = goal_candidates(Scene(), task.start_joints, task.obstacles.positions_m[0])
    assert len(inside) and scene.in_collision(inside[0])

    def is_valid(joints: np.ndarray) -> bool:
        return not scene.in_collision(joints)

    tic = time.perf_counter()
    result = plan_joint_path(is_valid, task.start_joints, inside[0], RRTConfig())
    assert not result.succeeded and result.waypoints is None
    assert result.status == "Invalid goal"
    assert time.perf_counter() - tic < 0.5  # detected up front, not after the time limit
    result = plan_joint_path(is_valid, inside[0], task.start_joints, RRTConfig())
    assert result.status == "Invalid start" and not result.succeeded
    env.close()


def shell_validity(goal: np.ndarray):
    """Joint space with a closed shell of invalid states around `goal`: unreachable goal."""

    def is_valid(joints: np.ndarray) -> bool:
        return not 0.2 < np.max(np.abs(joints - goal)) < 0.4

    return is_valid


def test_unreachable_goal_approximate_solution_is_a_failure():
    start, goal = np.zeros(6), np.full(6, 1.0)
    tic = time.perf_counter()
    result = plan_joint_path(shell_validity(goal), start, goal, RRTConfig(time_limit_s=0.2))
    elapsed_s = time.perf_counter() - tic
    # OMPL 2's RRTConnect reports its closest approach as an approximate solution (a truthy
    # status, with a path that stops short of the goal): the planner must not return it.
    assert result.status == "Approximate solution"
    assert not result.succeeded and result.waypoints is None
    # The time limit holds (with slack for a loaded machine).
    assert 0.2 <= result.solve_time_s < 0.4 and elapsed_s < 1.0


def test_tiny_time_limit_returns_failure_quickly():
    start, goal = np.zeros(6), np.full(6, 1.0)
    tic = time.perf_counter()
    result = plan_joint_path(shell_validity(goal), start, goal, RRTConfig(time_limit_s=0.005))
    assert not result.succeeded
    assert result.solve_time_s < 0.1 and time.perf_counter() - tic < 0.5
