"""Hindsight experience replay as pure functions of episode arrays.

Implements the standard HER goal strategies ("future", "final", "episode"; Andrychowicz et al.,
2017) and the paper's reversible HER (section "Reversed Vision-Based Hindsight Experience
Replay"): a failed episode is relabelled to the tip position just before its first collision and
truncated there, and the time-reversed collision-free part is added as extra data, which shows
the arm how to move back out of the obstacles' neighbourhood.

Every reward and terminal flag is recomputed through the env's vectorised ``compute_reward`` /
``compute_terminated`` callables; nothing here knows the reward's form.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from clamgen.replay.episode import (
    ACHIEVED_GOAL,
    DESIRED_GOAL,
    Batch,
    Episode,
    RewardFn,
    TerminatedFn,
    sparse_terminated,
)

HerStrategy = Literal["future", "final", "episode"]
"""Where a relabelled goal comes from: an achieved goal later in the same episode ("future"), the
episode's last one ("final"), or any one of the episode after its first step ("episode")."""


def sample_goal_indices(
    strategy: HerStrategy,
    steps: np.ndarray,
    first: np.ndarray | int,
    last: np.ndarray | int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Observation indices whose ``achieved_goal`` becomes the new goal.

    Args:
        strategy: HER strategy.
        steps: (N,) int, index of the observation each transition starts from.
        first: (N,) int or int, index of the first observation of each transition's episode.
        last: (N,) int or int, index of the last observation of each transition's episode;
            ``first <= steps < last``. Indices may be episode-local or buffer slots.
        rng: random generator (unused by "final").

    Returns:
        (N,) int64 indices in ``[steps + 1, last]`` ("future"), ``last`` ("final") or
        ``[first + 1, last]`` ("episode"): always achieved goals of *next* observations, so a
        transition can be relabelled as the one that reached its goal.
    """
    steps = np.asarray(steps, dtype=np.int64)
    last = np.broadcast_to(np.asarray(last, dtype=np.int64), steps.shape)
    if strategy == "future":
        return rng.integers(steps + 1, last + 1)
    if strategy == "final":
        return last.copy()
    if strategy == "episode":
        first = np.broadcast_to(np.asarray(first, dtype=np.int64), steps.shape)
        return rng.integers(first + 1, last + 1)
    raise ValueError(f"unknown HER strategy {strategy!r}")


def reward_and_done(
    next_achieved_goal: np.ndarray,
    desired_goal: np.ndarray,
    collisions: np.ndarray,
    compute_reward: RewardFn,
    compute_terminated: TerminatedFn | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Reward and terminal flag of transitions for the given goals.

    Args:
        next_achieved_goal: (N, G) goal achieved after each transition.
        desired_goal: (N, G) goal each transition is evaluated against.
        collisions: (N,) bool, whether each transition reported a collision.
        compute_reward: the env's vectorised ``compute_reward``.
        compute_terminated: the env's vectorised ``compute_terminated``; None derives it from a
            sparse reward (see :func:`sparse_terminated`).

    Returns:
        reward (N,) float32 and done (N,) float32 in {0, 1}.
    """
    info = {"collision": np.asarray(collisions, dtype=bool)}
    reward = np.asarray(compute_reward(next_achieved_goal, desired_goal, info), dtype=np.float32)
    terminated = compute_terminated or sparse_terminated(compute_reward)
    done = np.asarray(terminated(next_achieved_goal, desired_goal, info), dtype=np.float32)
    return reward, done


def transitions(
    episode: Episode,
    compute_reward: RewardFn,
    *,
    steps: np.ndarray | None = None,
    goal_indices: np.ndarray | None = None,
    compute_terminated: TerminatedFn | None = None,
) -> Batch:
    """Transitions of an episode, optionally with relabelled goals.

    Args:
        episode: the episode.
        compute_reward: the env's vectorised ``compute_reward``.
        steps: (N,) int step indices in [0, T); None means every step in order.
        goal_indices: (N,) int observation indices whose ``achieved_goal`` replaces
            ``desired_goal`` in both ``obs`` and ``next_obs``; None keeps the recorded goals and
            evaluates each step against the next observation's ``desired_goal`` (a moving target
            is where it is after the step).
        compute_terminated: see :func:`reward_and_done`.

    Returns:
        A :class:`Batch` of N transitions.
    """
    if steps is None:
        steps = np.arange(episode.num_steps)
    obs = {key: value[steps] for key, value in episode.obs.items()}
    next_obs = {key: value[steps + 1] for key, value in episode.obs.items()}
    if goal_indices is not None:
        goals = episode.obs[ACHIEVED_GOAL][goal_indices].astype(obs[DESIRED_GOAL].dtype)
        obs[DESIRED_GOAL] = goals
        next_obs[DESIRED_GOAL] = goals
    reward, done = reward_and_done(
        next_obs[ACHIEVED_GOAL],
        next_obs[DESIRED_GOAL],
        episode.collisions[steps],
        compute_reward,
        compute_terminated,
    )
    return Batch(
        obs=obs,
        action=episode.actions[steps],
        reward=reward,
        next_obs=next_obs,
        done=done,
        collision=episode.collisions[steps].astype(np.float32),
        demonstration=np.full(len(steps), float(episode.demonstration), np.float32),
    )


def with_goals(
    batch: Batch,
    relabel: np.ndarray,
    goals: np.ndarray,
    compute_reward: RewardFn,
    compute_terminated: TerminatedFn | None = None,
) -> Batch:
    """`batch` with the transitions where `relabel` is True given `goals` as their desired goal
    (in `obs` and `next_obs`), rewards and terminal flags recomputed for them.

    Args:
        batch: N transitions (its arrays are modified in place and returned).
        relabel: (N,) bool, which transitions get a new goal.
        goals: (relabel.sum(), G) the new goals, in the order of the True entries.
        compute_reward, compute_terminated: see :func:`reward_and_done`.
    """
    if not relabel.any():
        return batch
    obs, next_obs = batch["obs"], batch["next_obs"]
    goals = goals.astype(obs[DESIRED_GOAL].dtype)
    obs[DESIRED_GOAL][relabel] = goals
    next_obs[DESIRED_GOAL][relabel] = goals
    reward, done = reward_and_done(
        next_obs[ACHIEVED_GOAL][relabel],
        goals,
        batch["collision"][relabel].astype(bool),
        compute_reward,
        compute_terminated,
    )
    batch["reward"][relabel] = reward
    batch["done"][relabel] = done
    return batch


def _relabel(
    episode: Episode,
    strategy: HerStrategy,
    num_goals: int,
    rng: np.random.Generator,
    compute_reward: RewardFn,
    compute_terminated: TerminatedFn | None,
) -> Batch:
    steps = np.repeat(np.arange(episode.num_steps), num_goals)
    goal_indices = sample_goal_indices(strategy, steps, 0, episode.num_steps, rng)
    return transitions(
        episode,
        compute_reward,
        steps=steps,
        goal_indices=goal_indices,
        compute_terminated=compute_terminated,
    )


def relabel_future(
    episode: Episode,
    num_goals: int,
    rng: np.random.Generator,
    compute_reward: RewardFn,
    compute_terminated: TerminatedFn | None = None,
) -> Batch:
    """HER "future": each step relabelled with ``num_goals`` (k) goals achieved after it.

    Returns T * k transitions, step-major (the k copies of step 0 first). The original-goal
    transitions are not included; get them from :func:`transitions`.
    """
    return _relabel(episode, "future", num_goals, rng, compute_reward, compute_terminated)


def relabel_final(
    episode: Episode, compute_reward: RewardFn, compute_terminated: TerminatedFn | None = None
) -> Batch:
    """HER "final": every step relabelled with the episode's last achieved goal (T transitions)."""
    rng = np.random.default_rng(0)  # unused by "final"; keeps the signature free of it
    return _relabel(episode, "final", 1, rng, compute_reward, compute_terminated)


def relabel_episode_goals(
    episode: Episode,
    num_goals: int,
    rng: np.random.Generator,
    compute_reward: RewardFn,
    compute_terminated: TerminatedFn | None = None,
) -> Batch:
    """HER "episode": each step relabelled with ``num_goals`` (k) goals achieved anywhere in the
    episode after its first step. Returns T * k transitions, step-major."""
    return _relabel(episode, "episode", num_goals, rng, compute_reward, compute_terminated)


def _goal_reaching_episode(
    obs: dict[str, np.ndarray],
    actions: np.ndarray,
    executed_actions: np.ndarray,
    collisions: np.ndarray,
    goal: np.ndarray,
    compute_terminated: TerminatedFn,
) -> Episode:
    """An episode with a constant goal, success flags recomputed, cut at its first success (where
    the env would have terminated it)."""
    desired = obs[DESIRED_GOAL]
    obs = dict(obs)
    obs[DESIRED_GOAL] = np.broadcast_to(goal.astype(desired.dtype), desired.shape).copy()
    info = {"collision": collisions}
    successes = np.asarray(
        compute_terminated(obs[ACHIEVED_GOAL][1:], obs[DESIRED_GOAL][1:], info), dtype=bool
    )
    hits = np.flatnonzero(successes)
    end = int(hits[0]) + 1 if len(hits) else len(actions)
    return Episode(
        obs={key: value[: end + 1] for key, value in obs.items()},
        actions=actions[:end],
        executed_actions=executed_actions[:end],
        collisions=collisions[:end],
        successes=successes[:end],
    )


def reversible_her(
    episode: Episode,
    compute_reward: RewardFn,
    compute_terminated: TerminatedFn | None = None,
) -> tuple[Episode, ...]:
    """The paper's reversible HER for one episode.

    Let ``c`` be the first step that reported a collision (``T`` when none did), so observations
    0..c are the collision-free part and observation ``c`` is the state just before the
    collision. For a failed episode (see :attr:`Episode.failed`) this returns

    1. forward: steps 0..c-1 with the goal relabelled to ``achieved_goal[c]``;
    2. reversed: observations c, c-1, ..., 0 with actions ``-executed_actions[c-1], ...,
       -executed_actions[0]`` and the goal ``achieved_goal[0]`` (the start tip position). The
       *executed* action is negated because joint-limit clipping or a stop before contact can
       make it differ from the commanded one; the env is kinematic, so moving back along the
       same, collision-checked joint segment is a valid, collision-free step.

    Both carry ``desired_goal`` rewritten in every observation, success flags recomputed with
    ``compute_terminated`` (default: derived from ``compute_reward``), and are cut at their first
    success, where the env would have ended them; rewards follow from :func:`transitions`.
    Image observation keys are copied as they are; re-rendering them with the target at the new
    goal is the caller's job. Arrays other than ``desired_goal`` may be views of the input's.

    Returns:
        ``(forward, reversed)``, or ``()`` for an episode that succeeded without collision (it
        needs no relabelling) or collided at its first step (no collision-free part).
    """
    if not episode.failed:
        return ()
    hits = np.flatnonzero(episode.collisions)
    cut = int(hits[0]) if len(hits) else episode.num_steps
    if cut == 0:
        return ()
    terminated = compute_terminated or sparse_terminated(compute_reward)
    achieved = episode.obs[ACHIEVED_GOAL]
    no_collision = np.zeros(cut, dtype=bool)
    forward = _goal_reaching_episode(
        {key: value[: cut + 1] for key, value in episode.obs.items()},
        episode.actions[:cut],
        episode.executed_actions[:cut],
        no_collision,
        achieved[cut],
        terminated,
    )
    backward_actions = -episode.executed_actions[cut - 1 :: -1]
    backward = _goal_reaching_episode(
        {key: value[cut::-1] for key, value in episode.obs.items()},
        backward_actions,
        backward_actions,
        no_collision,
        achieved[0],
        terminated,
    )
    return forward, backward
