"""Blocked-path tasks: the obstacle-blind path collides, the goal and start are valid, the
sampling is seeded and deterministic."""

import gymnasium as gym
import numpy as np
import pytest

import clamgen  # noqa: F401  (registers the ids)
from clamgen.baselines import IKInterpolationPolicy
from clamgen.envs import MAX_EPISODE_STEPS, ReachEnv, reach_env
from clamgen.experiments.evaluate import run_episode
from clamgen.sim.scene import Obstacles, Scene
from clamgen.tasks import blocked, reach

BLOCKED_ID = "CLAMGen/ReachBlocked-v0"
SEEDS = range(60)  # training-range seeds


def make():
    """The registered env, bare (it truncates after 100 steps by itself)."""
    return ReachEnv(**{**gym.spec(BLOCKED_ID).kwargs, "max_episode_steps": MAX_EPISODE_STEPS})


def blind_motion_collides(scene: Scene, task: reach.Task) -> bool:
    """Move straight (joint space) from the start to the goal's IK solution nearest the start,
    as IK interpolation does, with the env's collision check; stop at the first contact."""
    target = IKInterpolationPolicy().target_joints(task.start_joints, task.target_position_m)
    scene.set_obstacles(task.obstacles)
    _, collided = scene.move_along(
        task.start_joints, target, reach_env.COLLISION_CHECK_RESOLUTION_RAD
    )
    return collided


def test_constants_agree_with_the_env():
    assert blocked.MAX_JOINT_DELTA_RAD == reach_env.MAX_JOINT_DELTA_RAD
    assert blocked.COLLISION_CHECK_RESOLUTION_RAD == reach_env.COLLISION_CHECK_RESOLUTION_RAD
    assert blocked.SUCCESS_DISTANCE_M == reach_env.SUCCESS_DISTANCE_M
    assert blocked.MAX_EPISODE_STEPS == reach_env.MAX_EPISODE_STEPS


def test_blind_goal_is_where_ik_interpolation_heads():
    rng = np.random.default_rng(0)
    for _ in range(10):
        start = reach.sample_start_joints(rng, Scene(), reach.GOAL_BOX_LOW_M, reach.GOAL_BOX_HIGH_M)
        goal = rng.uniform(reach.GOAL_BOX_LOW_M, reach.GOAL_BOX_HIGH_M)
        np.testing.assert_array_equal(
            blocked.blind_goal_joints(start, goal),
            IKInterpolationPolicy().target_joints(start, goal),
        )


def test_blocked_tasks_are_valid_and_block_the_blind_path_over_many_seeds():
    env = make()
    scene = Scene()
    for seed in SEEDS:
        env.reset(seed=seed)
        task = env.task
        assert len(task.obstacles) == 2
        # The same ranges and start rule as the obstacle tasks.
        goal = task.target_position_m
        assert (goal >= reach.GOAL_BOX_LOW_M).all() and (goal <= reach.GOAL_BOX_HIGH_M).all()
        centres = task.obstacles.positions_m
        assert (centres >= reach.OBSTACLE_CENTER_LOW_M).all()
        assert (centres <= reach.OBSTACLE_CENTER_HIGH_M).all()
        full = task.obstacles.half_sizes_m * 2
        assert (full >= 0.06 - 1e-9).all() and (full <= 0.09 + 1e-9).all()
        start_tip = env.scene.tip_position()
        assert np.linalg.norm(start_tip - goal) >= reach.MIN_START_GOAL_DISTANCE_M - 1e-9
        assert (start_tip >= reach.GOAL_BOX_LOW_M - 1e-6).all()
        assert (start_tip <= reach.GOAL_BOX_HIGH_M + 1e-6).all()
        # Collision-free start, a collision-free IK solution of the goal.
        assert not env.scene.in_collision(task.start_joints)
        assert len(reach.collision_free_solutions(env.scene, goal)) > 0
        # The obstacle-blind motion collides, and only because of the obstacles.
        assert blind_motion_collides(scene, task), f"seed {seed}: the blind path is free"
        assert not blind_motion_collides(
            scene, reach.Task(**{**task.__dict__, "obstacles": Obstacles.empty()})
        )


def test_ik_interpolation_rollouts_collide_and_fail():
    env = make()
    policy = IKInterpolationPolicy()
    for seed in range(8):
        record = run_episode(env, policy, seed)
        assert record.collided and not record.success, f"seed {seed}"


def test_sampling_is_seeded_and_deterministic():
    def task(seed):
        return blocked.sample_blocked_task(np.random.default_rng(seed), Scene())

    for seed in (0, 1, 12345):
        a, b = task(seed), task(seed)
        for key in ("start_joints", "target_position_m", "target_velocity_mps"):
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
        for key in ("kinds", "positions_m", "half_sizes_m"):
            np.testing.assert_array_equal(getattr(a.obstacles, key), getattr(b.obstacles, key))
    assert not np.array_equal(task(0).target_position_m, task(1).target_position_m)
    # Through the env: the same seed gives the same task, whatever came before.
    env = make()
    env.reset(seed=5)
    first = env.task
    env.reset(seed=6)
    env.reset(seed=5)
    np.testing.assert_array_equal(env.task.start_joints, first.start_joints)
    np.testing.assert_array_equal(env.task.obstacles.positions_m, first.obstacles.positions_m)


def test_the_blocker_takes_either_slot():
    scene = Scene()
    slots = set()
    for seed in range(30):
        task = blocked.sample_blocked_task(np.random.default_rng(seed), scene)
        path_target = blocked.blind_goal_joints(task.start_joints, task.target_position_m)
        path = blocked.blind_path(task.start_joints, path_target)
        for slot in range(2):
            one = Obstacles(
                task.obstacles.kinds[slot : slot + 1],
                task.obstacles.positions_m[slot : slot + 1],
                task.obstacles.half_sizes_m[slot : slot + 1],
            )
            scene.set_obstacles(one)
            if scene.collision_mask(path).any():
                slots.add(slot)
    assert slots == {0, 1}


def test_bad_input_is_refused_clearly():
    with pytest.raises(ValueError, match="num_obstacles >= 1"):
        blocked.sample_blocked_task(np.random.default_rng(0), Scene(), num_obstacles=0)
    with pytest.raises(ValueError, match="target speed"):
        blocked.sample_blocked_task(np.random.default_rng(0), Scene(), speed=-1.0)
