"""Rendering: RGB + metric depth in one pass per camera; the target lands where the camera
model projects it."""

import os
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from clamgen.robot import ur5
from clamgen.sim import constants as C
from clamgen.sim.render import (
    MultiViewRenderer,
    depth_to_uint8,
    project_points,
    uint8_to_depth,
)
from clamgen.sim.scene import Scene
from clamgen.sim.state import SimState, render_state


@pytest.fixture(scope="module")
def scene():
    scene = Scene()
    scene.set_joints(ur5.HOME_JOINTS)
    return scene


@pytest.mark.parametrize("size", [(64, 64), (48, 80)])
def test_every_view_shows_the_target_at_its_projected_pixel(scene, size):
    height, width = size
    renderer = MultiViewRenderer(scene.model, scene.camera_ids, height, width)
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(3):
        target = rng.uniform([0.4, -0.2, 0.05], [0.8, 0.2, 0.4])
        scene.set_target(target)
        rgb, depth = renderer.render(scene.data)
        assert rgb.shape == (C.NUM_CAMERAS, height, width, 3) and rgb.dtype == np.uint8
        assert depth.shape == (C.NUM_CAMERAS, height, width) and depth.dtype == np.float32
        for view, camera in enumerate(scene.camera_ids):
            col, row = project_points(scene.model, scene.data, camera, target, height, width)
            col, row = int(col), int(row)
            if not (1 <= row < height - 1 and 1 <= col < width - 1):
                continue
            rotation = scene.data.cam_xmat[camera].reshape(3, 3)
            axis_depth = -(target - scene.data.cam_xpos[camera]) @ rotation[:, 2]
            # Around the projected pixel: either the red target at its own depth, or something
            # nearer that hides it.
            window = (slice(row - 1, row + 2), slice(col - 1, col + 2))
            near_target = np.abs(depth[view][window] - axis_depth) < C.TARGET_RADIUS_M + 0.01
            if near_target.any():
                pixel = rgb[view][window][near_target].astype(int)
                assert ((pixel[:, 0] > 150) & (pixel[:, 1] < 80) & (pixel[:, 2] < 80)).any()
            else:
                assert depth[view][window].min() < axis_depth
            seen += near_target.any()
    assert seen > 0
    renderer.close()


def test_depth_is_metric_against_the_table_plane(scene):
    renderer = MultiViewRenderer(scene.model, scene.camera_ids[:1], 64, 64)
    _, depth = renderer.render(scene.data)
    camera = scene.camera_ids[0]
    # Cast the ray of a bottom-row pixel onto the table top and compare its axis depth.
    fy = 0.5 * 64 / np.tan(np.deg2rad(scene.model.cam_fovy[camera]) / 2)
    row, col = 62, 32
    direction_cam = np.array([(col + 0.5 - 32) / fy, -(row + 0.5 - 32) / fy, -1.0])
    rotation = scene.data.cam_xmat[camera].reshape(3, 3)
    direction = rotation @ direction_cam
    origin = scene.data.cam_xpos[camera]
    t = (C.TABLE_TOP_Z_M - origin[2]) / direction[2]
    assert depth[0, row, col] == pytest.approx(t, rel=0.02)
    renderer.close()


def test_depth_uint8_round_trip():
    depth = np.linspace(*C.DEPTH_RANGE_M, 50, dtype=np.float32)
    step = (C.DEPTH_RANGE_M[1] - C.DEPTH_RANGE_M[0]) / 255
    np.testing.assert_allclose(uint8_to_depth(depth_to_uint8(depth)), depth, atol=step / 2 + 1e-6)
    assert depth_to_uint8(np.array([0.0, 100.0])).tolist() == [0, 255]


def test_render_state_draws_the_target_elsewhere_and_restores_the_scene(scene):
    renderer = MultiViewRenderer(scene.model, scene.camera_ids[:2], 64, 64)
    scene.set_target(np.array([0.6, 0.0, 0.2]))
    before = SimState.capture(scene)
    here = render_state(scene, renderer, before)
    moved = SimState(ur5.HOME_JOINTS, np.array([0.5, 0.15, 0.1]), before.obstacles)
    there = render_state(scene, renderer, moved)
    assert here.shape == (2, 4, 64, 64) and here.dtype == np.uint8
    assert not np.array_equal(here, there)
    np.testing.assert_array_equal(scene.target_position, before.target_position_m)
    np.testing.assert_array_equal(render_state(scene, renderer, before), here)
    renderer.close()


def test_renderer_refuses_bad_arguments(scene):
    with pytest.raises(ValueError, match="positive"):
        MultiViewRenderer(scene.model, scene.camera_ids, 0, 64)
    with pytest.raises(ValueError, match="out of range"):
        MultiViewRenderer(scene.model, [scene.model.ncam], 64, 64)


def test_missing_gl_backend_gives_a_hint(monkeypatch):
    from clamgen.sim import render

    def broken(*args, **kwargs):
        raise mujoco.FatalError("no display")

    monkeypatch.setattr(render, "_gl_context_class", lambda backend: broken)
    with pytest.raises(RuntimeError, match="MUJOCO_GL=egl"):
        render.make_gl_context(8, 8)


def test_rendering_works_when_mujoco_was_imported_first():
    """A user's script that imports mujoco before clamgen (so MuJoCo chose its backend before
    clamgen set MUJOCO_GL=egl) still renders headless."""
    script = (
        "import mujoco\n"
        "from clamgen.envs import ReachEnv\n"
        "env = ReachEnv(num_obstacles=2, num_views=1, image_size=32, obs_mode='images')\n"
        "obs, _ = env.reset(seed=0)\n"
        "assert obs['images'][:, 3].std() > 0\n"
    )
    environment = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    subprocess.run([sys.executable, "-c", script], check=True, env=environment, timeout=120)
