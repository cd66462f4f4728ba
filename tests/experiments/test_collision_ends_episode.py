"""`env.collision_ends_episode`: in training, a collision is terminal, as evaluation counts it."""

import dataclasses

import numpy as np
import pytest
from test_train import tiny_config

from clamgen.baselines.ik_interpolation import IKInterpolationPolicy
from clamgen.envs import ReachEnv
from clamgen.experiments.config import EnvConfig
from clamgen.experiments.train import Trainer, make_env
from clamgen.replay.her import reward_and_done


def _first_collision(env: ReachEnv, seed: int) -> tuple[bool, bool, int]:
    """Step a blocked task along the blind path to its first collision: (terminated,
    truncated, steps)."""
    obs, _ = env.reset(seed=seed)
    blind = IKInterpolationPolicy()
    for step in range(1, 101):
        obs, _, terminated, truncated, info = env.step(blind.act(obs))
        if info["collision"] or terminated or truncated:
            assert info["collision"], "the blind path of a blocked task collides"
            return terminated, truncated, step
    raise AssertionError("no collision in 100 steps")


def test_a_collision_ends_the_episode_only_when_asked():
    ending = ReachEnv(num_obstacles=2, task_family="blocked", collision_ends_episode=True)
    going_on = ReachEnv(num_obstacles=2, task_family="blocked")
    for seed in range(3):
        terminated, truncated, steps = _first_collision(ending, seed)
        assert terminated and not truncated
        assert _first_collision(going_on, seed) == (False, False, steps)


def test_compute_terminated_agrees_with_step_and_counts_collisions_only_when_asked():
    env = ReachEnv(num_obstacles=2, task_family="blocked", collision_ends_episode=True)
    tip, far, near = np.zeros((3, 3)), np.full((3, 3), 0.1), np.full((3, 3), 0.005)
    info = {"collision": np.array([True, False, False])}
    np.testing.assert_array_equal(env.compute_terminated(tip, far, info), [True, False, False])
    np.testing.assert_array_equal(env.compute_terminated(tip, near, info), [True] * 3)
    np.testing.assert_array_equal(env.compute_terminated(tip, far, None), [False] * 3)
    paper = ReachEnv(num_obstacles=2, task_family="blocked")
    np.testing.assert_array_equal(paper.compute_terminated(tip, far, info), [False] * 3)
    # As the replay sees it: a colliding transition is terminal, with the penalty as its reward.
    env.collision_penalty = 0.5
    reward, done = reward_and_done(
        tip, far, info["collision"], env.compute_reward, env.compute_terminated
    )
    np.testing.assert_allclose(reward, [-0.51, -0.01, -0.01])
    np.testing.assert_array_equal(done, [1, 0, 0])


def test_only_training_envs_end_at_a_collision_and_the_replay_marks_it_terminal(tmp_path):
    env = EnvConfig(env_id="CLAMGen/ReachBlocked-v0", num_envs=2, collision_ends_episode=True)
    config = dataclasses.replace(tiny_config(tmp_path / "run", total=400), env=env)
    trainer = Trainer(config)
    assert [e.collision_ends_episode for e in trainer.envs] == [True, True]
    assert not trainer.eval_env.collision_ends_episode
    assert not make_env(env).collision_ends_episode
    trainer.run()
    batch = trainer.buffer.sample(256, np.random.default_rng(0))
    collided = batch["collision"] > 0
    assert collided.any(), "random actions on blocked tasks collide"
    np.testing.assert_array_equal(batch["done"][collided], 1.0)


@pytest.mark.parametrize("value", [1, "yes", None])
def test_a_non_boolean_switch_is_refused(value):
    with pytest.raises(ValueError, match="collision_ends_episode"):
        ReachEnv(num_obstacles=2, collision_ends_episode=value)
