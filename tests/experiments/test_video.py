"""`clamgen render`: a valid video of the expected length and size, plus GIF and summary."""

import json
from dataclasses import replace

import imageio.v2 as imageio
import pytest

from clamgen.baselines import IKInterpolationPolicy
from clamgen.envs import ENV_IDS
from clamgen.experiments.video import (
    HOLD_FINAL_FRAMES,
    OVERVIEW_SIZE,
    RenderConfig,
    render_env_rollouts,
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


class FirstEpisodeIdle(IKInterpolationPolicy):
    """IK interpolation that stays still for its first episode (which then fails)."""

    def __init__(self) -> None:
        super().__init__()
        self.episodes = 0

    def reset(self, env=None) -> None:
        super().reset(env)
        self.episodes += 1

    def act(self, obs):
        action = super().act(obs)
        return action * 0 if self.episodes == 1 else action


def test_render_films_only_the_outcome_asked_for(tmp_path):
    config = RenderConfig(
        env_id=ENV_IDS[0], num_episodes=1, num_views=0, outcome="success", out=tmp_path / "ik"
    )
    summary = render_rollouts(config, FirstEpisodeIdle(), "ik")
    # The first task (seed 1e9) failed and was left out; the second is the one filmed.
    assert summary["tasks_tried"] == 2 and summary["outcome"] == "success"
    [episode] = summary["episodes"]
    assert episode["success"] and episode["seed"] == config.seed + 1
    frames = imageio.get_reader(tmp_path / "ik.mp4").count_frames()
    assert frames == episode["steps"] + HOLD_FINAL_FRAMES
    assert json.loads((tmp_path / "ik.json").read_text())["tasks_tried"] == 2


def test_render_without_the_outcome_asked_for_writes_nothing(tmp_path):
    config = RenderConfig(
        env_id=ENV_IDS[0],
        num_views=0,
        num_episodes=1,
        outcome="failure",
        max_tries=2,
        out=tmp_path / "ik",
    )
    with pytest.raises(ValueError, match=r"none of the 2 tasks from seed \d+ ended in failure"):
        render_rollouts(config, IKInterpolationPolicy(), "ik")
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="--max-tries"):
        render_rollouts(replace(config, max_tries=0), IKInterpolationPolicy(), "ik")


class _SlowFirstIK(IKInterpolationPolicy):
    """IK interpolation whose first act of an episode takes three control periods (a plan)."""

    def reset(self, env=None) -> None:
        super().reset(env)
        self._first = True

    def act(self, obs):
        if self._first:
            import time

            from clamgen.envs.reach_env import CONTROL_DT_S

            time.sleep(3.2 * CONTROL_DT_S)
            self._first = False
        return super().act(obs)


def test_render_in_real_time_films_the_steps_held_while_acting(tmp_path):
    config = RenderConfig(
        policy="ik", env_id=ENV_IDS[0], num_episodes=1, num_views=0, out=tmp_path / "slow"
    )
    summary = render_rollouts(replace(config, real_time=True), _SlowFirstIK(), "ik")
    episode = summary["episodes"][0]
    assert episode["held_steps"] >= 3 and summary["real_time"] and summary["machine"]
    reader = imageio.get_reader(tmp_path / "slow.mp4")
    assert reader.count_frames() == episode["steps"] + HOLD_FINAL_FRAMES
    # Without it the same policy takes no simulated time: three steps fewer.
    plain = render_rollouts(replace(config, out=tmp_path / "plain"), _SlowFirstIK(), "ik")
    assert "held_steps" not in plain["episodes"][0] and "real_time" not in plain
    assert plain["episodes"][0]["steps"] == episode["steps"] - episode["held_steps"]
    with pytest.raises(ValueError, match="real-time needs a CLAMGen env"):
        render_env_rollouts(replace(config, real_time=True), _SlowFirstIK(), "ik", "Pendulum-v1")


def test_render_with_noisy_depth_says_so_and_needs_views(tmp_path):
    config = RenderConfig(
        policy="ik", env_id=ENV_IDS[0], num_episodes=1, num_views=1, depth_noise_m=0.003
    )
    views = {"num_views": 1, "obs_mode": "both", "image_size": 32}
    summary = render_rollouts(
        replace(config, out=tmp_path / "noisy"), IKInterpolationPolicy(), "ik", views
    )
    assert summary["depth_noise_m"] == 0.003 and summary["episodes"][0]["success"]
    with pytest.raises(ValueError, match="perturbs the views' depth"):
        render_rollouts(replace(config, out=tmp_path / "blind"), IKInterpolationPolicy(), "ik")
