"""The one path experience takes: episode -> hindsight relabelling -> re-rendering -> replay,
and replay -> batch.

- Storing (:meth:`EpisodePipeline.store`): a finished episode goes into the buffer as it was
  recorded; when reversible HER is on, its forward and time-reversed relabellings
  (:func:`clamgen.replay.her.reversible_her`, a pure function) are made here, once, and either
  stored at once (joint or obstacle-pose observations: nothing in them shows the goal) or sent to
  the re-rendering worker first (images: the target must be drawn at the new goal; paper,
  "Reversed Vision-Based Hindsight Experience Replay"), and stored when the frames come back
  (:meth:`collect`). Learning does not wait for them.
- Sampling (:meth:`sample`): transitions drawn uniformly from the buffer, a fraction
  `her_ratio` of them relabelled with a goal achieved later in their episode (standard HER,
  `her_strategy`), rewards and terminal flags recomputed for the goals they end up with
  (:func:`clamgen.replay.her.with_goals`, pure).

The buffer only stores and samples; nothing else relabels.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from clamgen.replay.buffer import ReplayBuffer
from clamgen.replay.episode import ACHIEVED_GOAL, Batch, Episode, RewardFn, TerminatedFn
from clamgen.replay.her import HerStrategy, reversible_her, sample_goal_indices, with_goals

__all__ = ["EpisodePipeline", "HindsightConfig"]


@dataclass(frozen=True)
class HindsightConfig:
    """Which hindsight relabelling the pipeline applies (each at one place, once)."""

    reversible: bool = True
    """Reversible HER: add the forward and time-reversed relabellings of every failed episode."""
    her_ratio: float = 0.8
    """Probability that a sampled transition gets a relabelled goal (sample-time HER)."""
    her_strategy: HerStrategy = "future"
    """Where sample-time HER goals come from."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.her_ratio <= 1.0:
            raise ValueError(f"her_ratio must be in [0, 1], got {self.her_ratio}")


class EpisodePipeline:
    """Episodes in, batches out; see the module docstring.

    Args:
        buffer: where episodes are stored.
        hindsight: the relabelling to apply.
        compute_reward: the env's vectorised `compute_reward`.
        compute_terminated: the env's vectorised terminal check (None: from a sparse reward).
        rerender: a :class:`~clamgen.replay.rerender.RerenderWorker` for image observations
            (relabelled episodes are re-rendered before they are stored); None stores them as
            they are, which is right only when no observation shows the goal.
        n_step, gamma: sampled batches hold n-step returns discounted by gamma
            (`ReplayBuffer.n_step`); n_step 1 leaves them one-step.
    """

    def __init__(
        self,
        buffer: ReplayBuffer,
        hindsight: HindsightConfig,
        compute_reward: RewardFn,
        compute_terminated: TerminatedFn | None = None,
        rerender: Any | None = None,
        n_step: int = 1,
        gamma: float = 1.0,
    ) -> None:
        self.buffer = buffer
        self.hindsight = hindsight
        self.compute_reward = compute_reward
        self.compute_terminated = compute_terminated
        self.rerender = rerender
        self.n_step = n_step
        self.gamma = gamma

    def relabel(self, episode: Episode) -> tuple[Episode, ...]:
        """The extra episodes hindsight makes of `episode` when it is stored (pure)."""
        if not self.hindsight.reversible:
            return ()
        return reversible_her(episode, self.compute_reward, self.compute_terminated)

    def store(self, episode: Episode, obstacles: Any = None) -> int:
        """Store a finished episode and its relabellings; returns the episodes stored now
        (re-rendered ones are stored later, by :meth:`collect`). `obstacles`: the scene's
        obstacles, which the re-rendering needs."""
        self.buffer.add_episode(episode)
        extras = self.relabel(episode)
        if self.rerender is None:
            for extra in extras:
                self.buffer.add_episode(extra)
            return 1 + len(extras)
        for extra in extras:
            self.rerender.submit(extra, obstacles)
        return 1

    def collect(self) -> int:
        """Store the re-rendered episodes that have come back (never blocks); their number."""
        return self._store_all(self.rerender.poll()) if self.rerender is not None else 0

    def flush(self, timeout_s: float | None = 600.0) -> int:
        """Wait for every episode still being re-rendered and store it (before a checkpoint,
        so that none is lost); their number."""
        return self._store_all(self.rerender.drain(timeout_s)) if self.rerender is not None else 0

    def _store_all(self, finished: Iterable[tuple[Any, Episode]]) -> int:
        count = 0
        for _, episode in finished:
            self.buffer.add_episode(episode)
            count += 1
        return count

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """`batch_size` transitions drawn uniformly, a fraction `her_ratio` relabelled."""
        slots = self.buffer.sample_slots(batch_size, rng)
        batch = self.buffer.transitions(slots)
        relabel = rng.random(batch_size) < self.hindsight.her_ratio
        first, last = self.buffer.episode_bounds(slots[relabel])
        goal_slots = sample_goal_indices(
            self.hindsight.her_strategy, slots[relabel], first, last, rng
        )
        goals = self.buffer.observations(ACHIEVED_GOAL, goal_slots)
        batch = with_goals(batch, relabel, goals, self.compute_reward, self.compute_terminated)
        if self.n_step > 1:
            batch = self.buffer.n_step(batch, slots, relabel, self.n_step, self.gamma)
        return batch

    def metrics(self) -> dict[str, float]:
        """The re-rendering worker's throughput, latency and backlog (empty without one)."""
        if self.rerender is None:
            return {}
        return {key: float(value) for key, value in self.rerender.stats.items()}

    def close(self) -> None:
        """Stop the re-rendering worker (episodes still pending are dropped)."""
        if self.rerender is not None:
            self.rerender.close()
