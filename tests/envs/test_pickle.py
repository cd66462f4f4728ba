"""Image envs survive pickle and deepcopy; each copy renders in a GL context of its own."""

import copy
import gc
import pickle

import gymnasium as gym
import numpy as np
import pytest

from clamgen.envs import ReachEnv
from clamgen.envs.wrappers import StackedViews


def assert_same_obs(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize("clone", [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))])
def test_a_copy_continues_the_episode_and_renders_the_same_images(clone, capfd):
    env = ReachEnv(
        num_obstacles=2, num_views=2, image_size=32, obs_mode="both", render_mode="rgb_array"
    )
    env.reset(seed=4)
    env.step(env.action_space.sample())
    overview = env.render()  # both renderers hold a live GL context when copied
    copied = clone(env)
    # The copy's renderer draws the copy's own model (obstacle sizes are set on the model).
    assert copied._renderer.model is copied.scene.model is not env.scene.model
    action = np.full(6, 0.5, np.float32)
    for _ in range(3):
        expected, reward, *_ = env.step(action)
        got, copied_reward, *_ = copied.step(action)
        assert_same_obs(expected, got)
        assert reward == copied_reward
    np.testing.assert_array_equal(copied.render(), env.render())
    assert overview.shape == (480, 640, 3)
    # A fresh episode on the copy sets its own obstacles; the images follow them.
    assert_same_obs(copied.reset(seed=9)[0], env.reset(seed=9)[0])
    copied.close()
    del copied
    gc.collect()
    env.step(action)  # the original's context is untouched
    env.close()
    assert "GLContext" not in capfd.readouterr().err


def test_a_wrapped_env_from_gym_make_pickles():
    env = StackedViews(
        gym.make("CLAMGen/ReachObstacles-v0", num_views=1, image_size=40, obs_mode="images")
    )
    env.reset(seed=2)
    restored = pickle.loads(pickle.dumps(env))
    action = env.action_space.sample()
    assert_same_obs(env.step(action)[0], restored.step(action)[0])
    assert restored.observation_space["images"].shape == (4, 40, 40)
    env.close()
    restored.close()
