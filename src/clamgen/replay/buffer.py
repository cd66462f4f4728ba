"""Episode replay buffer: stores whole episodes and samples transitions.

Stores whole episodes in preallocated numpy arrays, one array per observation key (so image keys
can be uint8), each observation once: an episode of T steps occupies T + 1 consecutive slots and
``next_obs`` of slot ``i`` is slot ``i + 1``. The buffer only stores and samples: hindsight
relabelling (standard HER at sample time, the paper's reversible HER when an episode is stored)
is done once, by :class:`clamgen.replay.pipeline.EpisodePipeline`, which reads the slots, episode
bounds and achieved goals it needs from here. The buffer never holds an env: rewards come from
the ``compute_reward`` callable it is given.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from clamgen.replay.episode import (
    ACHIEVED_GOAL,
    DESIRED_GOAL,
    Batch,
    Episode,
    RewardFn,
    TerminatedFn,
    sparse_terminated,
)
from clamgen.replay.her import HerStrategy, reward_and_done

ObsSpec = Mapping[str, tuple[tuple[int, ...], np.dtype]]
"""Shape (without the batch dim) and dtype of each stored observation key."""

# Per-slot bookkeeping besides observations and the action: collision flag (bool), index of the
# episode's first and last slot (2 x int64), whether the slot starts a transition (bool), and
# whether it belongs to a teacher's demonstration (bool).
_BOOKKEEPING_BYTES_PER_SLOT = 1 + 8 + 8 + 1 + 1
_NO_EPISODE = -1
# Checkpoints save the arrays in blocks of consecutive slots of about this size, and only the
# blocks changed since the previous checkpoint (`changed_blocks`); big enough that a 100k-slot
# image replay has a few hundred files, small enough that a checkpoint rewrites little.
BLOCK_BYTES = 8 * 2**20


@dataclass(frozen=True)
class ReplayConfig:
    """Replay buffer settings."""

    capacity: int = 1_000_000
    """Observation slots. An episode of T steps takes T + 1 of them and yields T transitions."""
    her_strategy: HerStrategy = "future"
    """Where relabelled goals come from (see :data:`clamgen.replay.her.HerStrategy`)."""
    her_ratio: float = 0.8
    """Probability that a sampled transition gets a relabelled goal (k = 4 in HER terms)."""
    reversible_her: bool = True
    """Add the paper's reversible-HER forward and reversed episodes of every failed episode
    (applied by the episode pipeline when the episode is stored)."""
    n_step: int = 1
    """Beyond the paper: n-step returns, the discounted reward of up to this many steps of
    the stored episode (after relabelling) before bootstrapping (Sutton 1988; Rainbow, R2D2).
    The sparse reward then reaches states n steps before a success in one update. 1: the
    paper's one-step target."""
    max_memory_fraction: float = 0.8
    """Refuse a capacity whose arrays need more than this fraction of the available memory."""

    def __post_init__(self) -> None:
        if self.capacity < 2:
            raise ValueError("capacity must hold at least one step (two observations)")
        if not 0.0 <= self.her_ratio <= 1.0:
            raise ValueError(f"her_ratio must be in [0, 1], got {self.her_ratio}")
        if isinstance(self.n_step, bool) or not isinstance(self.n_step, int) or self.n_step < 1:
            raise ValueError(f"replay.n_step must be an integer >= 1, got {self.n_step!r}")


def obs_spec_from_space(
    observation_space: spaces.Dict,
) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """The :data:`ObsSpec` of a Gymnasium Dict observation space of Box entries."""
    return {
        key: (tuple(space.shape), np.dtype(space.dtype))
        for key, space in observation_space.spaces.items()
    }


def nbytes_required(config: ReplayConfig, obs_spec: ObsSpec, action_dim: int) -> int:
    """Bytes the buffer's arrays take for ``config.capacity`` slots."""
    obs_bytes = sum(
        math.prod(shape) * np.dtype(dtype).itemsize for shape, dtype in obs_spec.values()
    )
    action_bytes = action_dim * np.dtype(np.float32).itemsize
    return config.capacity * (obs_bytes + action_bytes + _BOOKKEEPING_BYTES_PER_SLOT)


def available_memory_bytes() -> int:
    """Memory the system can give without swapping: MemAvailable from /proc/meminfo, else the
    free physical pages reported by ``os.sysconf``."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


class ReplayBuffer:
    """Ring buffer of whole episodes; uniform sampling over stored transitions.

    When a new episode does not fit before the end of the arrays, writing wraps to slot 0, and
    every old episode it overlaps is dropped whole, so a stored transition always has its next
    observation and its episode's future achieved goals.
    """

    def __init__(
        self,
        config: ReplayConfig,
        obs_spec: ObsSpec,
        action_dim: int,
        compute_reward: RewardFn,
        compute_terminated: TerminatedFn | None = None,
    ) -> None:
        """Allocate the arrays.

        Args:
            config: buffer settings.
            obs_spec: shape and dtype per observation key; must include ``achieved_goal`` and
                ``desired_goal``.
            action_dim: action size A.
            compute_reward: the env's vectorised ``env.unwrapped.compute_reward``.
            compute_terminated: the env's vectorised terminal check; None derives it from a
                sparse reward that is 0 exactly on success.

        Raises:
            ValueError: when the arrays would not fit into ``config.max_memory_fraction`` of the
                available memory.
        """
        for key in (ACHIEVED_GOAL, DESIRED_GOAL):
            if key not in obs_spec:
                raise ValueError(f"obs_spec lacks the goal key {key!r}")
        required = nbytes_required(config, obs_spec, action_dim)
        available = available_memory_bytes()
        if required > config.max_memory_fraction * available:
            raise ValueError(
                f"replay capacity {config.capacity} needs {required / 2**30:.2f} GiB, more than "
                f"{config.max_memory_fraction:.0%} of the {available / 2**30:.2f} GiB available; "
                "lower ReplayConfig.capacity"
            )
        self.config = config
        self.compute_reward = compute_reward
        self.compute_terminated = compute_terminated or sparse_terminated(compute_reward)
        capacity = config.capacity
        self._obs = {
            key: np.zeros((capacity, *shape), dtype) for key, (shape, dtype) in obs_spec.items()
        }
        self._action = np.zeros((capacity, action_dim), np.float32)
        self._collision = np.zeros(capacity, bool)
        self._demonstration = np.zeros(capacity, bool)
        self._first = np.full(capacity, _NO_EPISODE, np.int64)
        self._last = np.full(capacity, _NO_EPISODE, np.int64)
        self._starts_transition = np.zeros(capacity, bool)
        self._cursor = 0  # slot the next episode is written to
        self._high_water = 0  # slots [0, high_water) have been written at least once
        self._num_transitions = 0
        self._num_episodes = 0
        bytes_per_slot = nbytes_required(config, obs_spec, action_dim) // capacity
        self.slots_per_block = max(1, BLOCK_BYTES // bytes_per_slot)
        """Slots per checkpoint block (`block_arrays`)."""
        self._changed = np.ones(math.ceil(capacity / self.slots_per_block), bool)
        self.before_change: Callable[[int, int], None] | None = None
        """Called as ``before_change(first_block, last_block)`` before those blocks change: a
        checkpoint written in the background waits there until it has saved them."""

    def __len__(self) -> int:
        """Number of stored transitions."""
        return self._num_transitions

    @property
    def num_episodes(self) -> int:
        """Number of stored episodes (reversible-HER ones included)."""
        return self._num_episodes

    @property
    def nbytes(self) -> int:
        """Bytes held by the buffer's arrays."""
        arrays = [*self._obs.values(), self._action, self._collision, self._first, self._last]
        flags = self._starts_transition.nbytes + self._demonstration.nbytes
        return sum(a.nbytes for a in arrays) + flags

    def add_episode(self, episode: Episode) -> int:
        """Store one episode as it is (relabelling is the pipeline's job,
        :class:`clamgen.replay.pipeline.EpisodePipeline`). Returns 1."""
        self._write(episode)
        return 1

    def _write(self, episode: Episode) -> None:
        num_slots = episode.num_steps + 1
        if num_slots > self.config.capacity:
            raise ValueError(
                f"an episode of {episode.num_steps} steps needs {num_slots} slots, more than "
                f"the capacity {self.config.capacity}"
            )
        if self._cursor + num_slots > self.config.capacity:
            self._cursor = 0
        start, stop = self._cursor, self._cursor + num_slots
        self._drop_overlapping(start, stop)
        self._mark_changed(start, stop)
        for key, array in self._obs.items():
            array[start:stop] = episode.obs[key]
        self._action[start : stop - 1] = episode.actions
        self._collision[start : stop - 1] = episode.collisions
        self._demonstration[start:stop] = episode.demonstration
        self._first[start:stop] = start
        self._last[start:stop] = stop - 1
        self._starts_transition[start : stop - 1] = True
        self._cursor = stop
        self._high_water = max(self._high_water, stop)
        self._num_transitions += episode.num_steps
        self._num_episodes += 1

    def _drop_overlapping(self, start: int, stop: int) -> None:
        """Forget every stored episode with a slot in [start, stop)."""
        firsts = self._first[start:stop]
        for first in np.unique(firsts[firsts != _NO_EPISODE]):
            last = self._last[first]
            self._mark_changed(first, last + 1)
            self._first[first : last + 1] = _NO_EPISODE
            self._last[first : last + 1] = _NO_EPISODE
            self._starts_transition[first : last + 1] = False
            self._num_transitions -= int(last - first)
            self._num_episodes -= 1

    def _mark_changed(self, start: int, stop: int) -> None:
        first, last = start // self.slots_per_block, (stop - 1) // self.slots_per_block
        if self.before_change is not None:
            self.before_change(first, last)
        self._changed[first : last + 1] = True

    def state_dict(self) -> dict[str, np.ndarray]:
        """The stored data as plain numpy arrays (for `numpy.savez`; no pickling needed).

        The arrays are views of the buffer's own (no copy); checkpoints of large buffers save
        `block_arrays` instead, a block at a time."""
        state = self._slot_arrays(0, self._high_water)
        state["counters"] = self.counters()
        return state

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore from :meth:`state_dict` into this buffer's (equally configured) arrays."""
        counters = state["counters"]
        self._check_counters(counters)
        self._load_slots(0, {k: v for k, v in state.items() if k != "counters"}, int(counters[1]))
        self.set_counters(counters)
        self._changed[:] = True

    # ---------------------------------------------------------- checkpoint blocks
    @property
    def num_blocks(self) -> int:
        """Blocks that hold written slots: block ``b`` is slots
        ``[b * slots_per_block, min((b + 1) * slots_per_block, high_water))``."""
        return math.ceil(self._high_water / self.slots_per_block)

    def counters(self) -> np.ndarray:
        """Cursor, high-water mark, transition and episode counts, (4,) int64."""
        return np.array(
            [self._cursor, self._high_water, self._num_transitions, self._num_episodes], np.int64
        )

    def set_counters(self, counters: np.ndarray) -> None:
        """Set what :meth:`counters` returned, after the blocks were loaded."""
        self._check_counters(counters)
        cursor, high_water, num_transitions, num_episodes = (int(v) for v in counters)
        self._cursor, self._high_water = cursor, high_water
        self._num_transitions, self._num_episodes = num_transitions, num_episodes

    def block_arrays(self, block: int) -> dict[str, np.ndarray]:
        """The arrays of one block's written slots, as views (no copy)."""
        start = block * self.slots_per_block
        return self._slot_arrays(start, min(start + self.slots_per_block, self._high_water))

    def changed_blocks(self) -> list[int]:
        """Blocks with written slots changed since :meth:`mark_saved` (all before the first)."""
        return [int(b) for b in np.flatnonzero(self._changed[: self.num_blocks])]

    def mark_saved(self) -> None:
        """Record that every block is saved as it is now (after a checkpoint)."""
        self._changed[:] = False

    def load_slots(self, start: int, arrays: Mapping[str, np.ndarray]) -> None:
        """Copy saved slots (a :meth:`block_arrays` result, of any block size) into place from
        slot ``start``; call :meth:`set_counters` once every block is in."""
        stop = start + len(arrays["first"]) if "first" in arrays else start
        if not 0 <= start <= stop <= self.config.capacity:
            raise ValueError(
                f"saved replay slots {start}-{stop} lie outside the capacity {self.config.capacity}"
            )
        self._load_slots(start, arrays, stop)

    def _slot_arrays(self, start: int, stop: int) -> dict[str, np.ndarray]:
        arrays = {f"obs/{key}": array[start:stop] for key, array in self._obs.items()}
        return arrays | {
            "action": self._action[start:stop],
            "collision": self._collision[start:stop],
            "first": self._first[start:stop],
            "last": self._last[start:stop],
            "starts_transition": self._starts_transition[start:stop],
            "demonstration": self._demonstration[start:stop],
        }

    def _load_slots(self, start: int, arrays: Mapping[str, np.ndarray], stop: int) -> None:
        targets = self._slot_arrays(start, stop)
        if "demonstration" not in arrays:  # saved before teachers existed: none were
            arrays = {**arrays, "demonstration": np.zeros(stop - start, bool)}
        if set(arrays) != set(targets):
            raise ValueError(
                f"saved replay arrays {sorted(arrays)} differ from this buffer's {sorted(targets)}"
            )
        for key, target in targets.items():
            value = arrays[key]
            if value.shape != target.shape or value.dtype != target.dtype:
                raise ValueError(
                    f"saved replay array {key!r} is {value.dtype}{list(value.shape)}, this "
                    f"buffer expects {target.dtype}{list(target.shape)} for slots {start}-{stop}"
                )
            target[...] = value

    def _check_counters(self, counters: np.ndarray) -> None:
        high_water = int(counters[1])
        if high_water > self.config.capacity:
            raise ValueError(
                f"saved buffer holds {high_water} slots, more than the capacity "
                f"{self.config.capacity}"
            )

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """Transitions drawn uniformly, with their recorded goals (no relabelling)."""
        return self.transitions(self.sample_slots(batch_size, rng))

    def sample_slots(self, batch_size: int, rng: np.random.Generator) -> np.ndarray:
        """(batch_size,) int64 slots of transitions drawn uniformly from the stored ones."""
        if self._num_transitions == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        return self._sample_transition_slots(batch_size, rng)

    def transitions(self, slots: np.ndarray) -> Batch:
        """The transitions starting at `slots` (copies), rewards and `done` computed for the
        goals they were recorded with."""
        obs = {key: array[slots] for key, array in self._obs.items()}
        next_obs = {key: array[slots + 1] for key, array in self._obs.items()}
        reward, done = reward_and_done(
            next_obs[ACHIEVED_GOAL],
            next_obs[DESIRED_GOAL],
            self._collision[slots],
            self.compute_reward,
            self.compute_terminated,
        )
        return Batch(
            obs=obs,
            action=self._action[slots],
            reward=reward,
            next_obs=next_obs,
            done=done,
            collision=self._collision[slots].astype(np.float32),
            demonstration=self._demonstration[slots].astype(np.float32),
        )

    def n_step(
        self, batch: Batch, slots: np.ndarray, relabel: np.ndarray, n: int, gamma: float
    ) -> Batch:
        """`batch` (the transitions at `slots`, `relabel` marking those given a new goal, which
        their `obs` holds) turned into n-step transitions, in place: the reward is the
        discounted sum over up to `n` steps of the episode, stopping after a terminal step or
        at the episode's end; `next_obs` is the observation where it stopped; `discount` is
        gamma ** (steps summed), which the learner uses in place of gamma. A relabelled
        transition keeps its goal all along; the others follow the recorded goal of each step
        (a moving target is where it was)."""
        goal = batch["obs"][DESIRED_GOAL]
        size = len(slots)
        total = np.zeros(size, np.float64)
        done = np.zeros(size, bool)
        steps = np.zeros(size, np.int64)
        alive = np.ones(size, bool)
        for k in range(n):
            current = slots + k
            alive &= current < self._last[slots]  # transition `current` is in the episode
            rows = np.flatnonzero(alive)
            if len(rows) == 0:
                break
            after = current[rows] + 1
            desired = np.where(relabel[rows, None], goal[rows], self._obs[DESIRED_GOAL][after])
            reward, terminal = reward_and_done(
                self._obs[ACHIEVED_GOAL][after],
                desired,
                self._collision[current[rows]],
                self.compute_reward,
                self.compute_terminated,
            )
            total[rows] += gamma**k * reward
            steps[rows] += 1
            done[rows] = terminal > 0
            alive[rows] &= terminal == 0
        ends = slots + steps
        next_obs = {key: array[ends] for key, array in self._obs.items()}
        next_obs[DESIRED_GOAL][relabel] = goal[relabel]
        batch["reward"] = total.astype(np.float32)
        batch["done"] = done.astype(np.float32)
        batch["next_obs"] = next_obs
        batch["discount"] = (gamma**steps).astype(np.float32)
        return batch

    def episode_bounds(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First and last slot of the episode of each of `slots`, each (N,) int64."""
        return self._first[slots], self._last[slots]

    def observations(self, key: str, slots: np.ndarray) -> np.ndarray:
        """Observation `key` at `slots` (a copy), e.g. the achieved goals HER relabels with."""
        return self._obs[key][slots]

    def _sample_transition_slots(self, batch_size: int, rng: np.random.Generator) -> np.ndarray:
        """Uniform over stored transitions by rejection: all written slots but each episode's
        last one and the few freed by a wrap start a transition, so one round usually does."""
        chosen = np.empty(0, np.int64)
        while len(chosen) < batch_size:
            draw = rng.integers(0, self._high_water, size=2 * (batch_size - len(chosen)) + 8)
            chosen = np.concatenate([chosen, draw[self._starts_transition[draw]]])
        return chosen[:batch_size]
