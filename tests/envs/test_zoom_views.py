"""Zoomed views: a second camera at each view camera's position, turned to the target."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from clamgen.envs import ReachEnv
from clamgen.experiments.config import EnvConfig
from clamgen.experiments.pooled import JoinedViews


def _env(**kwargs) -> ReachEnv:
    options = dict(num_obstacles=2, num_views=2, image_size=24, obs_mode="both")
    return ReachEnv(**(options | kwargs))


def _looks_at_target(env: ReachEnv) -> None:
    scene = env.scene
    target = scene.data.mocap_pos[scene.target_mocap]
    for camera in scene.zoom_camera_ids[: env.num_views]:
        forward = -scene.data.cam_xmat[camera].reshape(3, 3)[:, 2]  # cameras look along -z
        towards = target - scene.data.cam_xpos[camera]
        assert forward @ towards / np.linalg.norm(towards) > 1 - 1e-9


def test_zoomed_views_follow_the_views_and_turn_to_the_target():
    plain, zoomed = _env(), _env(zoom_views=True)
    first, _ = plain.reset(seed=4)
    obs, _ = zoomed.reset(seed=4)
    assert obs["images"].shape == (4, 4, 24, 24)
    assert zoomed.observation_space["images"].shape == (4, 4, 24, 24)
    np.testing.assert_array_equal(obs["images"][:2], first["images"])  # the views unchanged
    assert not np.array_equal(obs["images"][2:], obs["images"][:2])
    _looks_at_target(zoomed)
    # The zoomed cameras sit where their views' cameras are.
    scene = zoomed.scene
    np.testing.assert_allclose(
        scene.data.cam_xpos[scene.zoom_camera_ids[:2]], scene.data.cam_xpos[scene.camera_ids[:2]]
    )
    zoomed.reset(seed=5)  # a new target: they turn to it
    _looks_at_target(zoomed)


def test_zoomed_env_passes_check_env():
    check_env(_env(zoom_views=True, task_family="blocked"), skip_render_check=True)


def test_bad_zoom_options_are_refused():
    with pytest.raises(ValueError, match="num_views >= 1"):
        ReachEnv(num_obstacles=2, zoom_views=True)
    with pytest.raises(ValueError, match="True or False"):
        _env(zoom_views=1)
    with pytest.raises(ValueError, match="zoom_views needs"):
        EnvConfig(zoom_views=True)


def test_config_passes_zoom_views_only_when_on():
    config = EnvConfig(num_views=2, obs_mode="both")
    assert "zoom_views" not in config.make_kwargs()  # every earlier policy's env options
    assert dataclasses.replace(config, zoom_views=True).make_kwargs()["zoom_views"] is True


def test_joined_views_index_like_their_concatenation():
    rng = np.random.default_rng(0)
    views, zoomed = rng.integers(0, 255, (2, 5, 3, 4, 6, 6), dtype=np.uint8)
    joined = JoinedViews(views, zoomed)
    assert joined.shape == (5, 6, 4, 6, 6) and len(joined) == 5
    index = np.array([3, 0, 3])
    np.testing.assert_array_equal(joined[index], np.concatenate([views, zoomed], 1)[index])
    with pytest.raises(ValueError, match="cannot join"):
        JoinedViews(views, zoomed[:4])
