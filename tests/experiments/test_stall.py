"""Stall counts (offline over pooled data, online in an episode) and the stall switch."""

from __future__ import annotations

import numpy as np
import pytest

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.pooled import file_lengths, subset
from clamgen.experiments.stall import (
    PROGRESS_M,
    ProgressWindow,
    StallBurst,
    StallCounter,
    StallSwitch,
    pool_episodes,
    pool_stall_counts,
    stall_counts,
)


def _obs(distance: float) -> dict[str, np.ndarray]:
    return {"achieved_goal": np.array([distance, 0.0, 0.0]), "desired_goal": np.zeros(3)}


def test_stall_counts_restart_at_progress_only():
    # 0.30 -> 0.20 progress; 0.198 is nearer but by less than PROGRESS_M; 0.25 is farther;
    # 0.19 is PROGRESS_M + nearer than the best (0.20): progress again.
    distances = np.array([0.30, 0.20, 0.198, 0.25, 0.20 - PROGRESS_M - 1e-4, 0.19])
    assert stall_counts(distances).tolist() == [0, 0, 1, 2, 0, 1]


def test_online_counter_matches_the_offline_counts():
    rng = np.random.default_rng(0)
    distances = np.abs(0.3 - np.cumsum(rng.normal(0.004, 0.01, 80)))
    counter = StallCounter()
    online = [counter.update(_obs(d)) for d in distances]
    assert online == stall_counts(distances).tolist()
    counter.reset()
    assert counter.update(_obs(1.0)) == 0


def test_pool_counts_follow_interleaved_episodes_within_each_file():
    rng = np.random.default_rng(1)
    # Two files; in each, two episodes whose rows interleave (as parallel collection writes
    # them). The second file reuses the first file's first task (another run, same seed).
    tasks = rng.normal(size=(3, 2, 8))
    episodes = [
        (0, tasks[0], np.array([0.3, 0.3, 0.3, 0.3])),
        (0, tasks[1], np.array([0.4, 0.3, 0.2])),
        (1, tasks[0], np.array([0.5, 0.4, 0.4, 0.4, 0.1])),
    ]
    rows = []  # (file, obstacles, distance, counts expected)
    for file in (0, 1):
        mine = [e for e in episodes if e[0] == file]
        steps = max(len(e[2]) for e in mine)
        for t in range(steps):
            for _, obstacles, distances in mine:
                if t < len(distances):
                    rows.append((file, obstacles, distances[t], int(stall_counts(distances)[t])))
    lengths = [sum(r[0] == f for r in rows) for f in (0, 1)]
    obstacles = np.stack([r[1] for r in rows]).astype(np.float32)
    desired = np.zeros((len(rows), 3), np.float32)
    achieved = desired.copy()
    achieved[:, 0] = [r[2] for r in rows]
    episode = pool_episodes(obstacles, lengths)
    assert len(np.unique(episode)) == 3
    counts = pool_stall_counts(achieved, desired, obstacles, lengths)
    assert counts.tolist() == [r[3] for r in rows]
    with pytest.raises(ValueError, match="rows"):
        pool_episodes(obstacles, [1, 2])


def test_subset_picks_rows_without_copying(tmp_path):
    array = np.arange(40, dtype=np.float32).reshape(10, 4)
    rows = subset({"x": array}, np.array([7, 2, 5]))["x"]
    assert len(rows) == 3 and rows.shape == (3, 4)
    np.testing.assert_array_equal(rows[np.array([2, 0])], array[[5, 7]])
    np.testing.assert_array_equal(np.asarray(rows), array[[7, 2, 5]])
    for i, n in enumerate((4, 6)):
        chunk = {"label": np.zeros((n, 6), np.float32)}
        ckpt.save_npz(tmp_path / "run" / "data" / f"iteration{i}.npz", chunk)
    assert file_lengths([(tmp_path / "run", None)]) == [4, 6]


class _Constant:
    def __init__(self, value: float) -> None:
        self.value, self.resets = value, 0

    def reset(self, env=None) -> None:
        self.resets += 1

    def act(self, obs) -> np.ndarray:
        return np.full(6, self.value)


def test_switch_hands_over_while_stalled_and_back_on_progress():
    policy, escape = _Constant(0.1), _Constant(-0.9)
    switch = StallSwitch(policy, escape, after_steps=2)
    switch.reset()
    assert policy.resets == escape.resets == 1
    distances = [0.3, 0.3, 0.3, 0.3, 0.2, 0.2]  # counts 0 1 2 3 0 1
    acted = [switch.act(_obs(d))[0] for d in distances]
    assert acted == [0.1, 0.1, -0.9, -0.9, 0.1, 0.1]
    assert (switch.num_steps, switch.num_escape_steps) == (6, 2)
    switch.reset()  # a new episode starts counting afresh
    assert switch.act(_obs(0.3))[0] == 0.1
    with pytest.raises(ValueError, match="after_steps"):
        StallSwitch(policy, escape, after_steps=0)


def test_burst_takes_random_steps_once_stalled_then_hands_back():
    policy = _Constant(0.1)
    burst = StallBurst(policy, after_steps=2, burst_steps=3, scale=0.5, seed=4)
    burst.reset()
    assert policy.resets == 1
    # counts 0 1 2 3 4 5 6 7 8: stalled from the third state on, never progressing again
    acted = [burst.act(_obs(0.3)) for _ in range(10)]
    random_steps = [i for i, a in enumerate(acted) if a[0] != 0.1]
    # a burst at the third state (3 steps), the policy for 2 steps, then the next burst
    assert random_steps == [2, 3, 4, 7, 8, 9]
    assert np.array_equal(acted[2], acted[4]) and not np.array_equal(acted[2], acted[7])
    assert all(np.abs(acted[i]).max() <= 0.5 for i in random_steps)
    assert (burst.num_steps, burst.num_burst_steps, burst.episode_bursts) == (10, 6, 2)
    burst.reset()  # the same episode acts the same again
    assert burst.episode_bursts == 0
    again = [burst.act(_obs(0.3)) for _ in range(10)]
    assert all(np.array_equal(a, b) for a, b in zip(acted, again, strict=True))


def test_burst_waits_while_the_episode_progresses():
    burst = StallBurst(_Constant(0.1), after_steps=2, burst_steps=3)
    burst.reset()
    acted = [burst.act(_obs(0.3 - 0.01 * t))[0] for t in range(8)]
    assert acted == [0.1] * 8 and burst.num_burst_steps == 0
    for options in ({"after_steps": 0}, {"burst_steps": 0}, {"scale": 0.0}, {"scale": 1.5}):
        with pytest.raises(ValueError):
            StallBurst(_Constant(0.1), **options)


def _window_rule(distances, steps, progress_m, arrived_m):
    """The hybrid planner's rule as it was written inline before `ProgressWindow`."""
    return (
        len(distances) > steps
        and distances[-1] > arrived_m
        and distances[-1 - steps] - distances[-1] < progress_m
    )


def test_progress_window_is_the_planners_rule_with_its_restarts():
    rng = np.random.default_rng(0)
    restarts = 0
    for _ in range(20):
        steps = int(rng.integers(1, 12))
        window = ProgressWindow(steps, 0.01, arrived_m=0.02)
        history = []
        # A tip that approaches, hovers and backs off at random.
        for distance in np.abs(0.3 + np.cumsum(rng.normal(-0.004, 0.01, 120))):
            history.append(float(distance))
            stalled = window.stalled(distance)
            assert stalled == _window_rule(history, steps, 0.01, 0.02)
            if stalled and rng.random() < 0.5:  # a plan: a fresh window
                window.restart()
                history = history[-1:]
                restarts += 1
        window.reset()
        assert not window.stalled(0.5)
    assert restarts > 10


def test_progress_window_waits_its_steps_and_not_at_the_target():
    window = ProgressWindow(3, 0.01, arrived_m=0.02)
    assert [window.stalled(d) for d in (0.20, 0.20, 0.20, 0.20)] == [False, False, False, True]
    window.reset()  # steady progress never stalls
    assert not any(window.stalled(0.3 - 0.011 * i) for i in range(20))
    window.reset()  # hovering at the target is arrival
    assert not any(window.stalled(0.01) for _ in range(10))
    with pytest.raises(ValueError, match="stuck_steps must be >= 1"):
        ProgressWindow(0)


def test_stall_burst_takes_its_escape_from_a_chooser_on_its_own_stream():
    drawn = []

    def choose(rng, obs):
        drawn.append(rng.uniform())
        return np.full(6, 0.5)

    burst = StallBurst(_Constant(0.1), after_steps=2, burst_steps=3, choose=choose)
    burst.reset()
    acted = [float(burst.act(_obs(0.3))[0]) for _ in range(6)]
    # Two stalled steps, then three of the chooser's command, then the policy again.
    assert acted == [0.1, 0.1, 0.5, 0.5, 0.5, 0.1]
    burst.reset()
    [burst.act(_obs(0.3)) for _ in range(3)]
    assert len(drawn) == 2 and drawn[0] == drawn[1]  # the stream restarts at each reset
