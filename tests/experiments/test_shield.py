"""The collision shield of a distilled vision student: predicted obstacles, clearance along the
env's step, and an end-to-end episode that never touches an obstacle when the shield sees the
true poses."""

import numpy as np
import pytest
from test_distill import distill_config, teacher  # noqa: F401 (fixtures)

from clamgen.envs import ReachEnv
from clamgen.envs.reach_env import MAX_JOINT_DELTA_RAD
from clamgen.experiments.distill import Distiller
from clamgen.experiments.shield import (
    MIN_HALF_SIZE_M,
    SHORTENED,
    ClearanceChecker,
    choose_action,
    load_shielded_student,
    perturbations,
    predicted_obstacles,
    step_checks,
    step_checks_many,
    step_clearance,
)
from clamgen.robot import ur5
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles, Scene


def test_pose_head_output_becomes_obstacles_in_metres():
    poses = np.array(
        [
            [0.9, 0.1, 8.0, 1.0, 4.0, 1.0, 2.0, 1.5],  # a box, lengths in units of 5 cm
            [0.2, 0.7, 10.0, -2.0, 3.0, 0.8, 0.1, -1.0],  # a cylinder with a negative size
        ]
    )
    obstacles = predicted_obstacles(poses, length_scale_m=0.05)
    assert list(obstacles.kinds) == [C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER]
    np.testing.assert_allclose(obstacles.positions_m, [[0.4, 0.05, 0.2], [0.5, -0.1, 0.15]])
    np.testing.assert_allclose(obstacles.half_sizes_m[0], [0.05, 0.1, 0.075])
    # A cylinder's half sizes are (radius, radius, half height); none below the minimum.
    np.testing.assert_allclose(obstacles.half_sizes_m[1], [0.04, 0.04, MIN_HALF_SIZE_M])


def test_clearance_falls_when_a_step_heads_into_an_obstacle():
    checker = ClearanceChecker(margin_m=0.03)
    env = ReachEnv(num_obstacles=0, obs_mode="joints")
    env.reset(seed=0)
    joints = env.unwrapped.scene.data.qpos.copy()
    action = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    # Nothing near: the step keeps the full margin.
    checker.set_obstacles(Obstacles.empty())
    assert checker.step_clearance(joints, action) == pytest.approx(0.03)
    # A box around where the step takes the tip: the step's clearance is negative (touching).
    scene = Scene()
    scene.set_joints(joints + action * MAX_JOINT_DELTA_RAD)
    box = Obstacles(
        np.array([C.OBSTACLE_BOX]), scene.tip_position()[None].copy(), np.full((1, 3), 0.05)
    )
    checker.set_obstacles(box)
    assert checker.step_clearance(joints, action) < 0
    # Moved away step by step, a cylinder is first touched, then within the margin, then
    # beyond it.
    clearances = []
    for offset in np.linspace(0.0, 1.0, 101):
        far = Obstacles(
            np.array([C.OBSTACLE_CYLINDER]),
            box.positions_m + np.array([0.0, offset, 0.0]),
            box.half_sizes_m,
        )
        checker.set_obstacles(far)
        clearances.append(checker.step_clearance(joints, action))
    assert clearances[0] < 0
    assert any(0 < c < 0.03 for c in clearances)
    assert clearances[-1] == pytest.approx(0.03)
    env.close()


def test_a_shielded_student_on_true_poses_never_touches_an_obstacle(
    tmp_path,
    base_policy,
    teacher,  # noqa: F811
):
    config = distill_config(tmp_path, base_policy, teacher, iterations=1)
    Distiller(config).run(show_progress=False)
    policy, env_kwargs = load_shielded_student(
        config.student.run_dir, margin_m=0.01, true_poses=True
    )
    env = ReachEnv(num_obstacles=2, task_family="blocked", max_episode_steps=25, **env_kwargs)
    collided = []
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        policy.reset(env)
        for _ in range(25):
            obs, _, terminated, truncated, info = env.step(policy.act(obs))
            collided.append(info["collision"])
            if terminated or truncated:
                break
    env.close()
    # The untrained student heads into the obstacle often; the shield turns it away every time.
    assert policy.num_shielded > 0
    assert not any(collided)


def test_step_checks_of_many_actions_are_each_actions_own():
    rng = np.random.default_rng(0)
    for trial in range(50):
        joints = rng.uniform(-3.0, 3.0, 6) if trial % 3 else ur5.JOINT_LIMITS[:, 1] - 1e-3
        actions = rng.uniform(-1.0, 1.0, (int(rng.integers(1, 12)), 6))
        actions *= rng.choice([0.0, 0.01, 1.0], (len(actions), 1))  # also none and tiny ones
        checks, starts = step_checks_many(joints, actions)
        each = [step_checks(joints, a) for a in actions]
        np.testing.assert_array_equal(checks, np.concatenate(each))
        np.testing.assert_array_equal(starts, np.cumsum([0] + [len(c) for c in each[:-1]]))


class _WallChecker:
    """Clearance to a wall where the first joint angle reaches 0.3 (a stand-in checker for
    choose_action's test)."""

    margin_m = 0.05

    def clearance(self, joints):
        return float(min(self.margin_m, 0.3 - joints[0]))

    def clearances(self, joints):
        return np.array([self.clearance(q) for q in joints])

    def step_clearance(self, joints, action):
        return step_clearance(self, joints, action)

    def step_clearances(self, joints, actions):
        return np.array([self.step_clearance(joints, a) for a in actions])


def test_the_shield_picks_the_nearest_alternative_that_keeps_the_clearance():
    """choose_action checks its alternatives nearest first and stops early: the same choice
    as scoring them all (the nearest that keeps the clearance, else the one keeping most)."""
    checker, offsets = _WallChecker(), perturbations(0)
    rng = np.random.default_rng(1)
    replaced = 0
    for _ in range(200):
        joints = np.zeros(6)
        joints[0] = rng.uniform(0.2, 0.3)
        action = np.tanh(rng.normal(0.0, 1.5, 6))
        pre = np.arctanh(np.clip(action, -0.995, 0.995))
        chosen, shielded = choose_action(checker, joints, action, pre, offsets)
        replaced += shielded
        if not shielded:
            continue
        keep = min(checker.clearance(joints), checker.margin_m)
        alternatives = [f * action for f in SHORTENED]
        alternatives += list(np.tanh(np.clip(pre, -3.0, 3.0) + offsets))
        scores = checker.step_clearances(joints, np.array(alternatives))
        distances = np.array([np.linalg.norm(a - action) for a in alternatives])
        ok = scores >= keep
        best = np.flatnonzero(ok)[np.argmin(distances[ok])] if ok.any() else np.argmax(scores)
        np.testing.assert_array_equal(chosen, np.asarray(alternatives[best], np.float32))
    assert replaced > 20
