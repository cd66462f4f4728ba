"""Roll out any `Policy` on seeded tasks and summarise: success, collisions, path, timing."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from clamgen.policy import Policy


@dataclass
class EpisodeRecord:
    """What one evaluation episode did."""

    seed: int
    reached: bool
    """The tip reached the target (collisions aside)."""
    collided: bool
    """Some step reported a collision."""
    steps: int
    tip_path_m: float
    """Length of the tip's path, metres."""
    act_times_s: list[float] = field(default_factory=list, repr=False)
    """Wall time of each `policy.act` call."""
    step_times_s: list[float] = field(default_factory=list, repr=False)
    """Wall time of each `env.step` call (kinematics, collision checks, rendering)."""

    @property
    def success(self) -> bool:
        """The spec's criterion: reached the target with no collision at any step."""
        return self.reached and not self.collided


StepHook = Callable[[dict[str, Any], dict[str, Any] | None, bool], None]
"""`hook(obs, info, done)`: called after the reset (info None) and after every step."""


def run_episode(
    env,
    policy: Policy,
    seed: int,
    options: dict | None = None,
    on_step: StepHook | None = None,
) -> EpisodeRecord:
    """One episode of `policy` in `env` (a Gymnasium env with a TimeLimit or its own): the one
    rollout loop of evaluation, the demo and the videos, which watch it through `on_step`."""
    obs, _ = env.reset(seed=seed, options=options)
    policy.reset(env)
    record = EpisodeRecord(seed=seed, reached=False, collided=False, steps=0, tip_path_m=0.0)
    if on_step is not None:
        on_step(obs, None, False)
    done = False
    while not done:
        start = time.perf_counter()
        action = policy.act(obs)
        record.act_times_s.append(time.perf_counter() - start)
        previous_tip = obs["achieved_goal"]
        start = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(action)
        record.step_times_s.append(time.perf_counter() - start)
        record.tip_path_m += float(np.linalg.norm(obs["achieved_goal"] - previous_tip))
        record.collided |= bool(info.get("collision", False))
        record.reached |= bool(info.get("is_success", False))
        record.steps += 1
        done = terminated or truncated
        if on_step is not None:
            on_step(obs, info, done)
    return record


def evaluate(env, policy: Policy, seeds) -> list[EpisodeRecord]:
    """One episode per seed."""
    return [run_episode(env, policy, int(seed)) for seed in seeds]


def summarize(records: list[EpisodeRecord]) -> dict[str, float]:
    """Success rate, collision rate, mean steps and tip path, median act time (ms)."""
    act_times = np.concatenate([r.act_times_s for r in records]) if records else np.zeros(1)
    return {
        "success_rate": float(np.mean([r.success for r in records])),
        "reach_rate": float(np.mean([r.reached for r in records])),
        "collision_rate": float(np.mean([r.collided for r in records])),
        "mean_steps": float(np.mean([r.steps for r in records])),
        "mean_tip_path_m": float(np.mean([r.tip_path_m for r in records])),
        "median_act_ms": float(np.median(act_times) * 1e3),
    }


class SACPolicy:
    """A trained SAC agent as a `Policy`: deterministic actions (tanh of the mean)."""

    def __init__(self, agent, deterministic: bool = True) -> None:
        self.agent = agent
        self.deterministic = deterministic

    def reset(self, env: Any | None = None) -> None:
        """Stateless."""

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self.agent.act(obs, deterministic=self.deterministic)
