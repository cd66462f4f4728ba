"""Episode and batch containers shared by hindsight relabelling and the replay buffer.

An episode of ``T`` steps keeps its ``T + 1`` observations once, so that ``next_obs`` of step
``t`` is observation ``t + 1`` (index arithmetic, never a second copy). Rewards are never stored:
they are recomputed through the environment's vectorised ``compute_reward`` whenever a goal is
relabelled (paper, "Reversed Vision-Based Hindsight Experience Replay").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict

import numpy as np

ACHIEVED_GOAL = "achieved_goal"
"""Observation key of the goal the agent reached (here: suction tip position, metres)."""
DESIRED_GOAL = "desired_goal"
"""Observation key of the goal the agent is asked to reach (target centre, metres)."""

RewardFn = Callable[[np.ndarray, np.ndarray, Any], np.ndarray]
"""``compute_reward(achieved_goal (..., G), desired_goal (..., G), info) -> reward (...)``, as on
a Gymnasium goal-conditioned env; ``info`` is None or a dict of arrays with leading dims (...)."""
TerminatedFn = Callable[[np.ndarray, np.ndarray, Any], np.ndarray]
"""``compute_terminated(achieved_goal, desired_goal, info) -> bool (...)``, same conventions."""


class Batch(TypedDict):
    """Transitions as numpy arrays with a leading batch dimension ``N``."""

    obs: dict[str, np.ndarray]
    """Observation per key, (N, ...) in the stored dtype."""
    action: np.ndarray
    """Commanded action, (N, A) float32 in [-1, 1]."""
    reward: np.ndarray
    """Reward recomputed for the (possibly relabelled) goal, (N,) float32."""
    next_obs: dict[str, np.ndarray]
    """Next observation per key, (N, ...); ``desired_goal`` equals the one in ``obs`` when the
    goal was relabelled."""
    done: np.ndarray
    """Terminal flag (success), not time-limit truncation, (N,) float32 in {0, 1}."""
    collision: np.ndarray
    """Whether the transition reported a collision, (N,) float32 in {0, 1} (the target of the
    stage-2 collision-prediction loss)."""
    demonstration: np.ndarray
    """Whether the transition comes from a teacher's episode, (N,) float32 in {0, 1} (the
    transitions a behaviour-cloning term imitates)."""
    discount: NotRequired[np.ndarray]
    """With n-step returns only: the factor on the bootstrapped value, gamma ** steps, (N,)
    float32 (absent: gamma)."""


@dataclass(frozen=True)
class Episode:
    """One episode of ``T >= 1`` steps as arrays.

    Observation ``t`` is the one the action ``t`` was taken from; observation ``T`` is the last
    one (after termination or truncation).
    """

    obs: dict[str, np.ndarray]
    """Observation per key, each (T + 1, ...); includes ``achieved_goal`` and ``desired_goal``."""
    actions: np.ndarray
    """Commanded actions, (T, A) float32 in [-1, 1]."""
    executed_actions: np.ndarray
    """Actions actually executed (after joint-limit clipping or a stop before contact),
    (T, A) float32 in [-1, 1]; equal to ``actions`` for envs that do not report them."""
    collisions: np.ndarray
    """Whether step t reported a collision, (T,) bool."""
    successes: np.ndarray
    """Whether step t reached the desired goal, (T,) bool."""
    demonstration: bool = False
    """Whether a teacher (not the agent) chose the actions (`loop.teacher_fraction`)."""

    def __post_init__(self) -> None:
        num_steps = len(self.actions)
        if num_steps < 1:
            raise ValueError("an episode needs at least one step")
        for key in (ACHIEVED_GOAL, DESIRED_GOAL):
            if key not in self.obs:
                raise ValueError(f"episode observations lack the key {key!r}")
        for key, value in self.obs.items():
            if len(value) != num_steps + 1:
                raise ValueError(
                    f"obs[{key!r}] has {len(value)} entries, expected T + 1 = {num_steps + 1}"
                )
        for name in ("executed_actions", "collisions", "successes"):
            if len(getattr(self, name)) != num_steps:
                raise ValueError(f"{name} has {len(getattr(self, name))} entries, expected T")

    @property
    def num_steps(self) -> int:
        """Number of steps (transitions) ``T``."""
        return len(self.actions)

    @property
    def failed(self) -> bool:
        """True unless the goal was reached without any collision (the spec's evaluation
        criterion); failed episodes are the ones reversible HER relabels."""
        return not bool(self.successes.any()) or bool(self.collisions.any())


def sparse_terminated(compute_reward: RewardFn) -> TerminatedFn:
    """Derive ``compute_terminated`` from a sparse reward that is 0 exactly on success.

    This is the HER convention (Andrychowicz et al., 2017) and holds for the CLAMGen envs, whose
    reward is -0.01 per step and 0 on success; ``info=None`` means "no collision", so a collision
    penalty never hides a success.
    """

    def compute_terminated(achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> Any:
        return np.asarray(compute_reward(achieved_goal, desired_goal, None)) >= 0.0

    return compute_terminated


class EpisodeRecorder:
    """Collects one episode step by step from a Gymnasium goal-conditioned env.

    Reads ``executed_action``, ``collision`` and ``is_success`` from each step's ``info`` and
    falls back to the commanded action, False and False for envs that do not report them.
    """

    def __init__(self, first_obs: Mapping[str, np.ndarray]) -> None:
        self._obs: dict[str, list[np.ndarray]] = {k: [np.asarray(v)] for k, v in first_obs.items()}
        self._actions: list[np.ndarray] = []
        self._executed: list[np.ndarray] = []
        self._collisions: list[bool] = []
        self._successes: list[bool] = []

    def __len__(self) -> int:
        return len(self._actions)

    def add(
        self, action: np.ndarray, next_obs: Mapping[str, np.ndarray], info: Mapping[str, Any]
    ) -> None:
        """Record the commanded ``action`` (A,), the observation it led to, and the step info."""
        for key, value in next_obs.items():
            self._obs[key].append(np.asarray(value))
        self._actions.append(np.asarray(action, dtype=np.float32))
        self._executed.append(np.asarray(info.get("executed_action", action), dtype=np.float32))
        self._collisions.append(bool(info.get("collision", False)))
        self._successes.append(bool(info.get("is_success", False)))

    def arrays(self) -> dict[str, np.ndarray]:
        """The partial episode as arrays (for checkpoints): obs/<key> (t + 1, ...), actions,
        executed_actions, collisions, successes (t, ...)."""
        arrays = {f"obs/{k}": np.stack(v) for k, v in self._obs.items()}
        arrays["actions"] = np.array(self._actions, np.float32)
        arrays["executed_actions"] = np.array(self._executed, np.float32)
        arrays["collisions"] = np.array(self._collisions, bool)
        arrays["successes"] = np.array(self._successes, bool)
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> EpisodeRecorder:
        """Rebuild a recorder from :meth:`arrays`."""
        recorder = cls({k[4:]: v[0] for k, v in arrays.items() if k.startswith("obs/")})
        for key, value in arrays.items():
            if key.startswith("obs/"):
                recorder._obs[key[4:]] = list(value)
        recorder._actions = list(arrays["actions"])
        recorder._executed = list(arrays["executed_actions"])
        recorder._collisions = [bool(c) for c in arrays["collisions"]]
        recorder._successes = [bool(c) for c in arrays["successes"]]
        return recorder

    def episode(self) -> Episode:
        """The recorded episode as arrays."""
        return Episode(
            obs={k: np.stack(v) for k, v in self._obs.items()},
            actions=np.stack(self._actions),
            executed_actions=np.stack(self._executed),
            collisions=np.array(self._collisions, dtype=bool),
            successes=np.array(self._successes, dtype=bool),
        )
