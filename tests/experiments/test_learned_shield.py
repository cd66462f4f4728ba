"""The learned collision head's pieces (results/stage2/shield/learned_shield.py) and the scene
restore of pooled rows it labels with."""

from __future__ import annotations

import numpy as np
import pytest

from clamgen.experiments.pooled import apply_row
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles, Scene


@pytest.fixture
def script(results_script):
    return results_script("stage2/shield/learned_shield.py")


def test_roc_area_is_the_chance_a_positive_outscores_a_negative(script):
    rng = np.random.default_rng(0)
    scores = rng.normal(size=60).round(1)  # ties count one half
    positive = rng.random(60) < 0.3
    pairs = scores[positive][:, None] - scores[~positive][None, :]
    expected = np.mean((pairs > 0) + 0.5 * (pairs == 0))
    assert np.isclose(script.roc_auc(scores, positive), expected)


def test_candidates_start_with_the_action_and_stay_in_the_box():
    from clamgen.experiments import learned_shield as module

    action = np.array([0.9, -0.2, 0.0, 0.4, -1.0, 0.1], np.float32)
    candidates = module.shield_candidates(action)
    assert candidates.shape == (1 + len(module.SCALES) + 12, 6)
    np.testing.assert_array_equal(candidates[0], action)
    np.testing.assert_allclose(candidates[1], 0.5 * action)
    assert np.abs(candidates).max() <= 1.0
    assert candidates[1 + len(module.SCALES), 0] == 1.0  # 0.9 + 0.5, clipped


def test_labelled_actions_follow_their_kinds(script):
    module = script
    rng = np.random.default_rng(1)
    student = rng.uniform(-1, 1, (5, 6)).astype(np.float32)
    teacher = rng.uniform(-1, 1, (5, 6)).astype(np.float32)
    actions = module._actions(student, teacher, np.random.default_rng(2))
    kinds = list(module.CANDIDATES)
    assert actions.shape == (5, len(kinds), 6) and np.abs(actions).max() <= 1.0
    np.testing.assert_array_equal(actions[:, kinds.index("student")], student)
    np.testing.assert_array_equal(actions[:, kinds.index("label")], teacher)
    assert not np.array_equal(actions[:, kinds.index("student+0.3")], student)


def test_a_pooled_row_restores_its_scene():
    obstacles = Obstacles(
        np.array([C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER]),
        np.array([[0.4, 0.1, 0.1], [0.3, -0.2, 0.15]]),
        np.array([[0.03, 0.04, 0.05], [0.035, 0.035, 0.06]]),
    )
    back = Obstacles.from_array(obstacles.as_array())
    np.testing.assert_array_equal(back.kinds, obstacles.kinds)
    np.testing.assert_allclose(back.positions_m, obstacles.positions_m, atol=1e-7)
    np.testing.assert_allclose(back.half_sizes_m, obstacles.half_sizes_m, atol=1e-7)
    scene = Scene()
    joints = np.array([0.1, -1.2, 1.3, -1.6, -1.5, 0.2])
    goal = np.array([0.45, 0.05, 0.2], np.float32)
    observation = np.concatenate([joints, np.zeros(3)]).astype(np.float32)
    apply_row(scene, observation, goal, obstacles.as_array())
    np.testing.assert_allclose(scene.data.qpos[:6], joints, atol=1e-6)
    np.testing.assert_allclose(scene.data.mocap_pos[scene.target_mocap], goal)
    np.testing.assert_allclose(scene.obstacles.positions_m, obstacles.positions_m, atol=1e-7)
