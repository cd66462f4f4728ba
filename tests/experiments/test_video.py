"""`clamgen render`: a valid video of the expected length and size, plus GIF and summary."""

import json

import imageio.v2 as imageio
import pytest

from clamgen.baselines import IKInterpolationPolicy
from clamgen.envs import ENV_IDS
from clamgen.experiments.video import (
    HOLD_FINAL_FRAMES,
    OVERVIEW_SIZE,
    RenderConfig,
    render_rollouts,
)


def test_render_writes_mp4_gif_and_summary(tmp_path):
    config = RenderConfig(
        policy="ik", env_id=ENV_IDS[0], num_episodes=2, num_views=2, out=tmp_path / "ik"
    )
    summary = render_rollouts(config, IKInterpolationPolicy(), "ik")
    steps = [episode["steps"] for episode in summary["episodes"]]
    assert all(episode["success"] for episode in summary["episodes"])
    reader = imageio.get_reader(tmp_path / "ik.mp4")
    # One frame per step, then the outcome held; no collisions on reach tasks.
    assert reader.count_frames() == sum(steps) + 2 * HOLD_FINAL_FRAMES
    height, width = OVERVIEW_SIZE
    frame = reader.get_data(0)
    assert frame.shape == (height, width + height // 2, 3)
    gif = imageio.mimread(tmp_path / "ik.gif")
    assert len(gif) > 2 and gif[0].shape[0] == height // 2
    assert json.loads((tmp_path / "ik.json").read_text())["episodes"][0]["steps"] == steps[0]


def test_render_refuses_bad_options(tmp_path):
    with pytest.raises(ValueError, match="env_id"):
        render_rollouts(RenderConfig(env_id="Pendulum-v1"), IKInterpolationPolicy(), "ik")
    with pytest.raises(ValueError, match="num_views"):
        render_rollouts(RenderConfig(num_views=7), IKInterpolationPolicy(), "ik")
