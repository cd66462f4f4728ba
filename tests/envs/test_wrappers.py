"""`StackedViews`: the views as one channel-first image that Stable-Baselines3 treats as such."""

import gymnasium as gym
import numpy as np
import pytest

from clamgen.envs.wrappers import StackedViews, unstack_views

NUM_VIEWS, IMAGE_SIZE = 2, 40


def make_env(**kwargs):
    kwargs = {"num_views": NUM_VIEWS, "image_size": IMAGE_SIZE, "obs_mode": "both", **kwargs}
    return StackedViews(gym.make("CLAMGen/ReachObstacles-v0", **kwargs))


def test_views_are_stacked_channel_first_in_view_order():
    env = make_env()
    raw, _ = env.unwrapped.reset(seed=3)
    obs, _ = env.reset(seed=3)
    space = env.observation_space["images"]
    assert space.shape == (NUM_VIEWS * 4, IMAGE_SIZE, IMAGE_SIZE) and space.dtype == np.uint8
    assert space.contains(obs["images"])
    # Channel 4 * v + c is channel c of view v; the other entries pass through.
    for v in range(NUM_VIEWS):
        np.testing.assert_array_equal(obs["images"][4 * v : 4 * v + 4], raw["images"][v])
    np.testing.assert_array_equal(unstack_views(obs["images"], NUM_VIEWS), raw["images"])
    np.testing.assert_array_equal(obs["desired_goal"], raw["desired_goal"])
    step_obs, *_ = env.step(env.action_space.sample())
    assert env.observation_space.contains(step_obs)
    goals = np.zeros((5, 3), np.float32)
    assert env.compute_reward(goals, goals, None).shape == (5,)
    env.close()


def test_refuses_an_env_without_images():
    with pytest.raises(ValueError, match="needs a Dict observation with 'images'"):
        StackedViews(gym.make("CLAMGen/Reach-v0"))


def test_sb3_sees_an_image_and_sac_her_runs_a_few_steps():
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.preprocessing import is_image_space
    from stable_baselines3.common.torch_layers import CombinedExtractor, NatureCNN

    # Short episodes: SB3's HER buffer samples only from finished episodes.
    env = make_env(max_episode_steps=10)
    # As its CombinedExtractor asks (check_channels=False: any number of stacked channels).
    assert is_image_space(env.observation_space["images"])
    # Without the wrapper SB3 does not see an image (it would flatten the views into an MLP).
    assert not is_image_space(env.unwrapped.observation_space["images"])
    model = sb3.SAC(
        "MultiInputPolicy",
        env,
        buffer_size=200,
        learning_starts=20,
        batch_size=8,
        replay_buffer_class=sb3.HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 2, "goal_selection_strategy": "future"},
        policy_kwargs={"net_arch": [32, 32], "features_extractor_kwargs": {"cnn_output_dim": 16}},
        seed=0,
    )
    extractor = model.policy.actor.features_extractor
    assert isinstance(extractor, CombinedExtractor)
    assert isinstance(extractor.extractors["images"], NatureCNN)
    model.learn(total_timesteps=40)
    assert model.num_timesteps == 40 and model.replay_buffer.size() > 0
    obs, _ = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (6,) and np.all(np.abs(action) <= 1)
    env.close()
