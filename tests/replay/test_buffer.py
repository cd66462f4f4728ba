"""Replay buffer: next-observation index arithmetic, wrap-around, memory; HER at sample time and
reversible HER on insert through the episode pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from clamgen.replay.buffer import (
    ReplayBuffer,
    ReplayConfig,
    available_memory_bytes,
    nbytes_required,
    obs_spec_from_space,
)
from clamgen.replay.episode import Episode
from clamgen.replay.pipeline import EpisodePipeline, HindsightConfig

STEP_REWARD = -0.01
OBS_SPEC = {
    "observation": ((2,), np.dtype(np.float32)),
    "achieved_goal": ((3,), np.dtype(np.float32)),
    "desired_goal": ((3,), np.dtype(np.float32)),
}


def exact_reward(achieved_goal: np.ndarray, desired_goal: np.ndarray, info) -> np.ndarray:
    """0 when the goal is hit exactly, else -0.01; a collision costs another 1.0."""
    reward = np.where(np.all(achieved_goal == desired_goal, axis=-1), 0.0, STEP_REWARD)
    if info is not None:
        reward = reward - np.asarray(info["collision"], dtype=float)
    return reward


def labelled_episode(episode_id: int, num_steps: int, collide_at: int | None = None) -> Episode:
    """Observation t of episode e is (e, t); achieved goal (e, t, 0); desired goal (e, -1, 0).

    The desired goal is never reached, so the episode failed.
    """
    t = np.arange(num_steps + 1, dtype=np.float32)
    e = np.full_like(t, episode_id)
    collisions = np.zeros(num_steps, bool)
    if collide_at is not None:
        collisions[collide_at] = True
    actions = np.stack([e[:-1], t[:-1]], axis=1)
    return Episode(
        obs={
            "observation": np.stack([e, t], axis=1),
            "achieved_goal": np.stack([e, t, np.zeros_like(t)], axis=1),
            "desired_goal": np.stack([e, -np.ones_like(t), np.zeros_like(t)], axis=1),
        },
        actions=actions,
        executed_actions=actions,
        collisions=collisions,
        successes=np.zeros(num_steps, bool),
    )


def make_buffer(capacity: int, **overrides) -> ReplayBuffer:
    config = ReplayConfig(capacity=capacity, reversible_her=False, **overrides)
    return ReplayBuffer(config, OBS_SPEC, action_dim=2, compute_reward=exact_reward)


def make_pipeline(capacity: int, **hindsight) -> EpisodePipeline:
    """A buffer behind the pipeline that relabels (no reversible HER unless asked)."""
    hindsight.setdefault("reversible", False)
    buffer = make_buffer(capacity)
    return EpisodePipeline(buffer, HindsightConfig(**hindsight), exact_reward)


def check_batch(batch, lengths: dict[int, int]) -> None:
    """Every sampled transition is consistent with the labelled episodes still stored."""
    episode_id = batch["obs"]["observation"][:, 0].astype(int)
    step = batch["obs"]["observation"][:, 1].astype(int)
    assert set(episode_id) <= set(lengths)
    num_steps = np.array([lengths[e] for e in episode_id])
    assert np.all((step >= 0) & (step < num_steps))
    np.testing.assert_array_equal(batch["next_obs"]["observation"][:, 0], episode_id)
    np.testing.assert_array_equal(batch["next_obs"]["observation"][:, 1], step + 1)
    np.testing.assert_array_equal(batch["action"][:, 1], step)
    np.testing.assert_array_equal(batch["next_obs"]["desired_goal"], batch["obs"]["desired_goal"])
    goal = batch["obs"]["desired_goal"]
    np.testing.assert_array_equal(goal[:, 0], episode_id)  # goals never cross episodes
    relabelled = goal[:, 1] >= 0
    goal_step = goal[relabelled, 1].astype(int)
    assert np.all(goal_step >= step[relabelled] + 1)
    assert np.all(goal_step <= num_steps[relabelled])
    reached = relabelled & (goal[:, 1] == step + 1)
    np.testing.assert_allclose(batch["reward"], np.where(reached, 0.0, STEP_REWARD))
    np.testing.assert_array_equal(batch["done"], reached)


def test_next_obs_and_her_goals_stay_inside_episodes_across_wraparound() -> None:
    pipeline = make_pipeline(capacity=23, her_ratio=0.5)
    buffer = pipeline.buffer
    rng = np.random.default_rng(0)
    lengths: dict[int, int] = {}
    for episode_id, num_steps in enumerate([3, 5, 1, 6, 4, 2, 7, 3, 5, 6, 1, 4]):
        pipeline.store(labelled_episode(episode_id, num_steps))
        lengths[episode_id] = num_steps
        batch = pipeline.sample(400, rng)
        stored = set(batch["obs"]["observation"][:, 0].astype(int))
        assert episode_id in stored  # the newest episode is always kept
        check_batch(batch, lengths)
        # Episodes overwritten by the ring are dropped whole: what is sampled is what is counted.
        assert len(buffer) == sum(lengths[e] for e in stored)
        assert len(buffer) + buffer.num_episodes <= 23


def test_ring_drops_overwritten_episodes_whole() -> None:
    buffer = make_buffer(capacity=10, her_ratio=0.0)
    for episode_id, num_steps in enumerate([4, 3, 5]):  # slots 0-4, 5-8, then wraps to 0-5
        buffer.add_episode(labelled_episode(episode_id, num_steps))
    assert buffer.num_episodes == 1 and len(buffer) == 5
    batch = buffer.sample(200, np.random.default_rng(0))
    assert set(batch["obs"]["observation"][:, 0].astype(int)) == {2}


def test_sampling_is_uniform_over_transitions() -> None:
    buffer = make_buffer(capacity=100, her_ratio=0.0)
    buffer.add_episode(labelled_episode(0, 1))
    buffer.add_episode(labelled_episode(1, 9))
    batch = buffer.sample(20_000, np.random.default_rng(0))
    share = np.mean(batch["obs"]["observation"][:, 0] == 0)
    assert abs(share - 0.1) < 0.01


def test_the_buffer_alone_never_relabels() -> None:
    config = ReplayConfig(capacity=50, her_ratio=1.0, reversible_her=True)
    buffer = ReplayBuffer(config, OBS_SPEC, action_dim=2, compute_reward=exact_reward)
    assert buffer.add_episode(labelled_episode(0, 4, collide_at=2)) == 1
    assert buffer.num_episodes == 1
    batch = buffer.sample(100, np.random.default_rng(0))
    np.testing.assert_array_equal(batch["obs"]["desired_goal"][:, 1], -1.0)


def test_without_her_goals_and_rewards_are_recorded_ones() -> None:
    buffer = make_buffer(capacity=50, her_ratio=0.0)
    buffer.add_episode(labelled_episode(0, 4, collide_at=2))
    batch = buffer.sample(100, np.random.default_rng(0))
    np.testing.assert_array_equal(batch["obs"]["desired_goal"][:, 1], -1.0)
    collided = batch["obs"]["observation"][:, 1] == 2
    np.testing.assert_allclose(batch["reward"], np.where(collided, STEP_REWARD - 1.0, STEP_REWARD))
    assert not batch["done"].any()


def test_final_strategy_relabels_to_episode_end() -> None:
    pipeline = make_pipeline(capacity=50, her_ratio=1.0, her_strategy="final")
    pipeline.store(labelled_episode(0, 4))
    batch = pipeline.sample(100, np.random.default_rng(0))
    np.testing.assert_array_equal(batch["obs"]["desired_goal"][:, 1], 4.0)
    last_step = batch["obs"]["observation"][:, 1] == 3
    np.testing.assert_array_equal(batch["done"], last_step)


def test_reversible_her_episodes_are_added_on_insert() -> None:
    pipeline = make_pipeline(capacity=100, reversible=True, her_ratio=0.0)
    buffer = pipeline.buffer
    assert pipeline.store(labelled_episode(0, 6, collide_at=4)) == 3
    # original 6 steps + forward 4 + reversed 4
    assert buffer.num_episodes == 3 and len(buffer) == 14
    batch = pipeline.sample(2000, np.random.default_rng(0))
    step = batch["obs"]["observation"][:, 1]
    next_step = batch["next_obs"]["observation"][:, 1]
    backwards = next_step == step - 1
    assert backwards.any()
    np.testing.assert_array_equal(batch["action"][backwards, 1], -next_step[backwards])


def test_memory_is_reported_and_checked() -> None:
    spec = {**OBS_SPEC, "image": ((4, 8, 8), np.dtype(np.uint8))}
    config = ReplayConfig(capacity=64, reversible_her=False)
    buffer = ReplayBuffer(config, spec, action_dim=2, compute_reward=exact_reward)
    assert buffer.nbytes == nbytes_required(config, spec, action_dim=2)
    assert buffer._obs["image"].dtype == np.uint8
    too_big = ReplayConfig(capacity=available_memory_bytes() // 8)
    with pytest.raises(ValueError, match="GiB"):
        ReplayBuffer(too_big, spec, action_dim=2, compute_reward=exact_reward)


def test_rejects_empty_sample_and_oversized_episode() -> None:
    buffer = make_buffer(capacity=4)
    with pytest.raises(ValueError, match="empty"):
        buffer.sample(1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="capacity"):
        buffer.add_episode(labelled_episode(0, 4))


def test_obs_spec_from_space() -> None:
    from gymnasium import spaces

    space = spaces.Dict(
        {
            "observation": spaces.Box(-1, 1, (6,), np.float32),
            "image": spaces.Box(0, 255, (2, 4, 4), np.uint8),
        }
    )
    assert obs_spec_from_space(space) == {
        "observation": ((6,), np.dtype(np.float32)),
        "image": ((2, 4, 4), np.dtype(np.uint8)),
    }


def test_n_step_returns_sum_discounted_rewards_and_stop_at_terminal_steps_and_episode_ends():
    gamma = 0.5
    buffer = make_buffer(100)
    buffer.add_episode(labelled_episode(0, 6))  # slots 0..6, never reaches its goal
    slots = np.array([0, 4, 5])
    batch = buffer.n_step(buffer.transitions(slots), slots, np.zeros(3, bool), 3, gamma)
    # Three -0.01 steps from slot 0; two from slot 4 and one from 5, cut by the episode's end.
    np.testing.assert_allclose(batch["reward"], [-0.01 * 1.75, -0.01 * 1.5, -0.01], rtol=1e-6)
    np.testing.assert_allclose(batch["discount"], [gamma**3, gamma**2, gamma])
    np.testing.assert_array_equal(batch["done"], [0, 0, 0])
    np.testing.assert_array_equal(batch["next_obs"]["observation"][:, 1], [3, 6, 6])
    # Relabelled to the tip position of observation 2: from slot 0, -0.01 then the success.
    relabel = np.array([True, False, False])
    batch = buffer.transitions(slots)
    batch["obs"]["desired_goal"][0] = buffer.observations("achieved_goal", np.array([2]))[0]
    batch = buffer.n_step(batch, slots, relabel, 3, gamma)
    np.testing.assert_allclose(batch["reward"][0], -0.01, rtol=1e-6)
    assert batch["done"][0] == 1 and batch["discount"][0] == gamma**2
    np.testing.assert_array_equal(batch["next_obs"]["observation"][0], [0, 2])
    np.testing.assert_array_equal(batch["next_obs"]["desired_goal"][0], [0, 2, 0])


def test_the_pipeline_samples_n_step_returns_only_when_asked():
    buffer = make_buffer(1000)
    one = EpisodePipeline(buffer, HindsightConfig(reversible=False, her_ratio=0.5), exact_reward)
    three = EpisodePipeline(
        buffer, HindsightConfig(reversible=False, her_ratio=0.5), exact_reward, n_step=3, gamma=0.9
    )
    for e in range(5):
        one.store(labelled_episode(e, 10))
    assert "discount" not in one.sample(64, np.random.default_rng(0))
    batch = three.sample(64, np.random.default_rng(0))
    steps = batch["next_obs"]["observation"][:, 1] - batch["obs"]["observation"][:, 1]
    assert set(np.unique(steps)) <= {1, 2, 3} and (steps == 3).any()
    np.testing.assert_allclose(batch["discount"], 0.9**steps, rtol=1e-6)
    with pytest.raises(ValueError, match="n_step"):
        ReplayConfig(n_step=0)
