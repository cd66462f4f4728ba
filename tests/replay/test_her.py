"""Hindsight relabelling on hand-built episodes: goals, recomputed rewards, reversal, truncation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clamgen.replay.episode import Episode, EpisodeRecorder, sparse_terminated
from clamgen.replay.her import (
    relabel_episode_goals,
    relabel_final,
    relabel_future,
    reversible_her,
    sample_goal_indices,
    transitions,
)

STEP_REWARD = -0.01
COLLISION_PENALTY = -0.1
THRESHOLD = 0.5


def reach_reward(achieved_goal: np.ndarray, desired_goal: np.ndarray, info) -> np.ndarray:
    """Sparse reach reward of the env contract: -0.01 unless within THRESHOLD, plus a penalty."""
    distance = np.linalg.norm(achieved_goal - desired_goal, axis=-1)
    reward = np.where(distance < THRESHOLD, 0.0, STEP_REWARD)
    if info is not None:
        reward = reward + COLLISION_PENALTY * np.asarray(info["collision"], dtype=float)
    return reward


def make_episode(
    tip_x: list[float],
    collisions: list[bool] | None = None,
    goal_x: float = 10.0,
    executed_scale: float = 0.5,
) -> Episode:
    """Episode whose tip moves along x through ``tip_x`` (T + 1 entries); observation = (x, t)."""
    num_steps = len(tip_x) - 1
    tip = np.zeros((num_steps + 1, 3), np.float32)
    tip[:, 0] = tip_x
    actions = np.arange(1, 2 * num_steps + 1, dtype=np.float32).reshape(num_steps, 2) / 100
    collisions = [False] * num_steps if collisions is None else collisions
    successes = np.abs(tip[1:, 0] - goal_x) < THRESHOLD
    return Episode(
        obs={
            "observation": np.stack([tip[:, 0], np.arange(num_steps + 1)], axis=1),
            "achieved_goal": tip,
            "desired_goal": np.tile(np.float32([goal_x, 0.0, 0.0]), (num_steps + 1, 1)),
        },
        actions=actions,
        executed_actions=executed_scale * actions,
        collisions=np.array(collisions, dtype=bool),
        successes=successes,
    )


def test_transitions_keep_recorded_goals_and_recompute_rewards() -> None:
    episode = make_episode([0.0, 1.0, 2.0, 9.8], collisions=[False, True, False])
    batch = transitions(episode, reach_reward)
    np.testing.assert_array_equal(batch["obs"]["observation"][:, 1], [0, 1, 2])
    np.testing.assert_array_equal(batch["next_obs"]["observation"][:, 1], [1, 2, 3])
    np.testing.assert_allclose(batch["reward"], [STEP_REWARD, STEP_REWARD + COLLISION_PENALTY, 0])
    np.testing.assert_array_equal(batch["done"], [0, 0, 1])
    np.testing.assert_array_equal(batch["action"], episode.actions)
    assert batch["reward"].dtype == np.float32 and batch["done"].dtype == np.float32


def test_relabel_final_uses_last_achieved_goal() -> None:
    episode = make_episode([0.0, 1.0, 2.0, 3.0, 4.0])
    batch = relabel_final(episode, reach_reward)
    expected_goal = np.float32([4.0, 0.0, 0.0])
    for key in ("obs", "next_obs"):
        np.testing.assert_array_equal(batch[key]["desired_goal"], np.tile(expected_goal, (4, 1)))
    np.testing.assert_allclose(batch["reward"], [STEP_REWARD] * 3 + [0.0])
    np.testing.assert_array_equal(batch["done"], [0, 0, 0, 1])
    np.testing.assert_array_equal(batch["obs"]["achieved_goal"], episode.obs["achieved_goal"][:4])
    np.testing.assert_array_equal(
        batch["next_obs"]["achieved_goal"], episode.obs["achieved_goal"][1:]
    )


def test_relabel_future_goals_come_from_later_steps() -> None:
    tip_x = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    episode = make_episode(tip_x)
    batch = relabel_future(
        episode, num_goals=200, rng=np.random.default_rng(0), compute_reward=reach_reward
    )
    steps = batch["obs"]["observation"][:, 1].astype(int)
    np.testing.assert_array_equal(steps, np.repeat(np.arange(5), 200))
    goal_index = batch["obs"]["desired_goal"][:, 0].astype(int)  # tip x equals its time index
    np.testing.assert_array_equal(batch["next_obs"]["desired_goal"], batch["obs"]["desired_goal"])
    assert np.all(goal_index >= steps + 1) and np.all(goal_index <= 5)
    for t in range(5):  # every later achieved goal is drawn
        assert set(goal_index[steps == t]) == set(range(t + 1, 6))
    reached = goal_index == steps + 1
    np.testing.assert_allclose(batch["reward"], np.where(reached, 0.0, STEP_REWARD))
    np.testing.assert_array_equal(batch["done"], reached)


def test_relabel_episode_goals_come_from_whole_episode() -> None:
    episode = make_episode([0.0, 1.0, 2.0, 3.0])
    batch = relabel_episode_goals(episode, 100, np.random.default_rng(1), reach_reward)
    goal_index = batch["obs"]["desired_goal"][:, 0].astype(int)
    assert set(goal_index) == {1, 2, 3}
    assert len(batch["action"]) == 300


def test_sample_goal_indices_in_buffer_slots() -> None:
    rng = np.random.default_rng(0)
    steps = np.array([10, 12, 13])
    future = sample_goal_indices("future", steps, 10, 14, rng)
    assert np.all((future > steps) & (future <= 14))
    np.testing.assert_array_equal(sample_goal_indices("final", steps, 10, 14, rng), [14, 14, 14])
    with pytest.raises(ValueError, match="strategy"):
        sample_goal_indices("past", steps, 10, 14, rng)  # type: ignore[arg-type]


def test_reversible_her_truncates_at_first_collision_and_reverses() -> None:
    episode = make_episode(
        [0.0, 1.0, 2.0, 3.0, 4.0, 5.0], collisions=[False, False, False, True, False]
    )
    forward, backward = reversible_her(episode, reach_reward)

    # Forward: steps 0..2, goal = tip at observation 3 (just before the colliding step 3).
    goal = np.float32([3.0, 0.0, 0.0])
    assert forward.num_steps == 3
    np.testing.assert_array_equal(forward.obs["observation"], episode.obs["observation"][:4])
    np.testing.assert_array_equal(forward.obs["desired_goal"], np.tile(goal, (4, 1)))
    np.testing.assert_array_equal(forward.actions, episode.actions[:3])
    np.testing.assert_array_equal(forward.executed_actions, episode.executed_actions[:3])
    np.testing.assert_array_equal(forward.successes, [False, False, True])
    assert not forward.collisions.any()
    batch = transitions(forward, reach_reward)
    np.testing.assert_allclose(batch["reward"], [STEP_REWARD, STEP_REWARD, 0.0])
    np.testing.assert_array_equal(batch["done"], [0, 0, 1])

    # Reversed: observations 3, 2, 1, 0; actions = negated executed actions; goal = start tip.
    start = np.float32([0.0, 0.0, 0.0])
    np.testing.assert_array_equal(backward.obs["observation"][:, 1], [3, 2, 1, 0])
    np.testing.assert_array_equal(backward.obs["achieved_goal"][:, 0], [3.0, 2.0, 1.0, 0.0])
    np.testing.assert_array_equal(backward.obs["desired_goal"], np.tile(start, (4, 1)))
    expected_actions = -episode.executed_actions[[2, 1, 0]]
    np.testing.assert_array_equal(backward.actions, expected_actions)
    np.testing.assert_array_equal(backward.executed_actions, expected_actions)
    assert not np.array_equal(backward.actions, -episode.actions[[2, 1, 0]])
    np.testing.assert_array_equal(backward.successes, [False, False, True])
    assert not backward.collisions.any()
    batch = transitions(backward, reach_reward)
    np.testing.assert_allclose(batch["reward"], [STEP_REWARD, STEP_REWARD, 0.0])
    np.testing.assert_array_equal(batch["done"], [0, 0, 1])
    # Pure: the input episode is unchanged.
    np.testing.assert_array_equal(episode.obs["desired_goal"][:, 0], 10.0)


def test_reversible_her_without_collision_uses_episode_end() -> None:
    episode = make_episode([0.0, 1.0, 2.0, 3.0])
    forward, backward = reversible_her(episode, reach_reward)
    assert forward.num_steps == backward.num_steps == 3
    np.testing.assert_array_equal(forward.obs["desired_goal"][:, 0], 3.0)
    np.testing.assert_array_equal(backward.obs["achieved_goal"][:, 0], [3.0, 2.0, 1.0, 0.0])


def test_reversible_her_cuts_at_first_success_under_new_goal() -> None:
    # Observation 2 (x=2.8) is already within 0.5 m of the new goal x=3.0: the env would have
    # ended the episode there.
    episode = make_episode([0.0, 1.0, 2.8, 3.0, 4.0], collisions=[False, False, False, True])
    forward, backward = reversible_her(episode, reach_reward)
    assert forward.num_steps == 2
    np.testing.assert_array_equal(forward.successes, [False, True])
    assert backward.num_steps == 3


def test_reversible_her_skips_clean_success_and_first_step_collision() -> None:
    assert reversible_her(make_episode([8.0, 9.0, 10.0]), reach_reward) == ()
    collided_first = make_episode([0.0, 1.0, 2.0], collisions=[True, False])
    assert reversible_her(collided_first, reach_reward) == ()


def test_reversible_her_relabels_success_reached_after_a_collision() -> None:
    episode = make_episode([7.0, 8.0, 9.0, 10.0], collisions=[False, True, False])
    assert episode.failed
    forward, backward = reversible_her(episode, reach_reward)
    np.testing.assert_array_equal(forward.obs["desired_goal"][:, 0], 8.0)
    np.testing.assert_array_equal(backward.obs["achieved_goal"][:, 0], [8.0, 7.0])


@settings(max_examples=50, deadline=None)
@given(
    tip_x=st.lists(st.floats(-5.0, 5.0, width=32), min_size=2, max_size=12),
    collision_seed=st.integers(0, 2**16),
)
def test_reversible_her_invariants(tip_x: list[float], collision_seed: int) -> None:
    num_steps = len(tip_x) - 1
    collisions = np.random.default_rng(collision_seed).random(num_steps) < 0.2
    episode = make_episode(tip_x, collisions=list(collisions), goal_x=100.0)
    result = reversible_her(episode, reach_reward)
    hits = np.flatnonzero(collisions)
    cut = int(hits[0]) if len(hits) else num_steps
    if cut == 0:
        assert result == ()
        return
    terminated = sparse_terminated(reach_reward)
    for relabelled, order in zip(result, (np.arange(cut + 1), np.arange(cut, -1, -1)), strict=True):
        n = relabelled.num_steps
        assert 1 <= n <= cut
        for key in ("observation", "achieved_goal"):
            np.testing.assert_array_equal(relabelled.obs[key], episode.obs[key][order[: n + 1]])
        goal = episode.obs["achieved_goal"][order[-1]]
        np.testing.assert_array_equal(relabelled.obs["desired_goal"], np.tile(goal, (n + 1, 1)))
        success = terminated(relabelled.obs["achieved_goal"][1:], goal, None)
        np.testing.assert_array_equal(relabelled.successes, success)
        assert relabelled.successes[-1] and not relabelled.successes[:-1].any()
        assert not relabelled.collisions.any()
    backward = result[1]
    np.testing.assert_array_equal(
        backward.actions, -episode.executed_actions[cut - 1 :: -1][: backward.num_steps]
    )


def test_episode_recorder_reads_contract_info() -> None:
    first = {"observation": np.zeros(2), "achieved_goal": np.zeros(3), "desired_goal": np.ones(3)}
    recorder = EpisodeRecorder(first)
    info = {"executed_action": np.float32([0.5, 0.0]), "collision": True, "is_success": False}
    recorder.add(np.float32([1.0, 0.0]), first, info)
    recorder.add(np.float32([0.0, 1.0]), first, {})  # a plain Gymnasium env reports nothing
    episode = recorder.episode()
    assert episode.num_steps == 2 and len(episode.obs["observation"]) == 3
    np.testing.assert_array_equal(episode.executed_actions, [[0.5, 0.0], [0.0, 1.0]])
    np.testing.assert_array_equal(episode.collisions, [True, False])
    assert episode.failed


def test_episode_rejects_inconsistent_lengths() -> None:
    episode = make_episode([0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="T \\+ 1"):
        Episode(
            obs={k: v[:2] for k, v in episode.obs.items()},
            actions=episode.actions,
            executed_actions=episode.executed_actions,
            collisions=episode.collisions,
            successes=episode.successes,
        )
