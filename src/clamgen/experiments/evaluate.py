"""Roll out any `Policy` on seeded tasks and summarise: success, collisions, path, timing."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from clamgen.envs import ReachEnv
from clamgen.envs.reach_env import CONTROL_DT_S
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
    collisions_reported: bool = True
    """Every step's info said whether it collided (CLAMGen envs do; other goal envs may not,
    and then `collided` stays False without meaning anything)."""
    tip_measured: bool = True
    """`tip_path_m` is the gripper tip's path: true in CLAMGen envs, whose `achieved_goal` is
    the tip position in metres; another env's achieved goal may be anything."""
    held_steps: int = 0
    """With `real_time`: the steps the arm held still while the policy computed (counted in
    `steps`)."""

    @property
    def success(self) -> bool:
        """The spec's criterion: reached the target with no collision at any step."""
        return self.reached and not self.collided

    def outcome(self) -> dict[str, Any]:
        """Seed, success, reached, collided and steps, as the videos and the viewer report
        each episode (JSON-ready)."""
        return {
            "seed": self.seed,
            "success": self.success,
            "reached": self.reached,
            "collided": self.collided,
            "steps": self.steps,
        }


StepHook = Callable[[dict[str, Any], dict[str, Any] | None, bool], None]
"""`hook(obs, info, done)`: called after the reset (info None) and after every step."""


def run_episode(
    env,
    policy: Policy,
    seed: int,
    options: dict | None = None,
    on_step: StepHook | None = None,
    real_time: bool = False,
) -> EpisodeRecord:
    """One episode of `policy` in `env` (a Gymnasium env with a TimeLimit or its own): the one
    rollout loop of evaluation, the demo and the videos, which watch it through `on_step`.

    `real_time` (a CLAMGen env; beyond the paper): an act that takes longer than the control
    period (`CONTROL_DT_S`, 50 ms) costs a step of the arm holding still (a zero command) for
    each whole period it took, before its action is applied: the target moves on meanwhile and
    those steps count towards the time limit. A policy with `skipped(steps)` is told how many
    steps it did not see (a planner that estimates the target's velocity). Without it, acting
    takes no simulated time."""
    if real_time and not isinstance(env.unwrapped, ReachEnv):
        raise ValueError("real_time needs a CLAMGen env (its control period)")
    obs, _ = env.reset(seed=seed, options=options)
    policy.reset(env)
    record = EpisodeRecord(seed=seed, reached=False, collided=False, steps=0, tip_path_m=0.0)
    record.tip_measured = isinstance(env.unwrapped, ReachEnv)
    if on_step is not None:
        on_step(obs, None, False)

    def step(action) -> bool:
        """One env step, recorded; whether the episode is over."""
        nonlocal obs
        previous_tip = obs["achieved_goal"]
        start = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(action)
        record.step_times_s.append(time.perf_counter() - start)
        record.tip_path_m += float(np.linalg.norm(obs["achieved_goal"] - previous_tip))
        record.collided |= bool(info.get("collision", False))
        record.collisions_reported &= "collision" in info
        record.reached |= bool(info.get("is_success", False))
        record.steps += 1
        done = terminated or truncated
        if on_step is not None:
            on_step(obs, info, done)
        return done

    done = False
    while not done:
        start = time.perf_counter()
        action = policy.act(obs)
        record.act_times_s.append(time.perf_counter() - start)
        late = int(record.act_times_s[-1] // CONTROL_DT_S) if real_time else 0
        for _ in range(late):
            record.held_steps += 1
            if done := step(np.zeros_like(action)):
                break
        if late and hasattr(policy, "skipped"):
            policy.skipped(late)
        done = done or step(action)
    return record


def evaluate(env, policy: Policy, seeds, real_time: bool = False) -> list[EpisodeRecord]:
    """One episode per seed (`run_episode`)."""
    return [run_episode(env, policy, int(seed), real_time=real_time) for seed in seeds]


def summarize(records: list[EpisodeRecord]) -> dict[str, float]:
    """Success rate, collision rate, mean steps and tip path, median act time (ms). The
    collision rate and tip path are left out when the env does not provide them (see
    `EpisodeRecord.collisions_reported` and `tip_measured`), rather than logged as zeros."""
    act_times = np.concatenate([r.act_times_s for r in records]) if records else np.zeros(1)
    summary = {
        "success_rate": float(np.mean([r.success for r in records])),
        "reach_rate": float(np.mean([r.reached for r in records])),
        "collision_rate": float(np.mean([r.collided for r in records])),
        "mean_steps": float(np.mean([r.steps for r in records])),
        "mean_tip_path_m": float(np.mean([r.tip_path_m for r in records])),
        "median_act_ms": float(np.median(act_times) * 1e3),
    }
    if not all(r.collisions_reported for r in records):
        del summary["collision_rate"]
    if not all(r.tip_measured for r in records):
        del summary["mean_tip_path_m"]
    return summary


def per_task(records: list[EpisodeRecord]) -> dict[str, list | float]:
    """Each episode's outcome, in order (`success`, `collided`, `steps`: lists for JSON, to
    compare policies task by task on the same seeds), and the median act time over all their
    steps (`act_median_ms`)."""
    act_times = np.concatenate([r.act_times_s for r in records]) if records else np.zeros(1)
    return {
        "success": [bool(r.success) for r in records],
        "collided": [bool(r.collided) for r in records],
        "steps": [int(r.steps) for r in records],
        "act_median_ms": float(np.median(act_times) * 1e3),
    }


class SACPolicy:
    """A trained SAC agent as a `Policy`: deterministic actions (tanh of the mean), or, with
    `critic_candidates` > 0 (a stage-2 agent), the best of that many candidates by its critic
    (`ResidualAgent.act_by_critic`, seeded by `seed` at each reset)."""

    def __init__(
        self, agent, deterministic: bool = True, critic_candidates: int = 0, seed: int = 0
    ) -> None:
        self.agent = agent
        self.deterministic = deterministic
        self.critic_candidates = critic_candidates
        self.seed = seed
        self._generator = None
        self._warm = False

    def reset(self, env: Any | None = None) -> None:
        """Restart the candidates' random stream, so each episode acts the same every time.

        At the first reset with an env, act once on a blank observation of its space first:
        the networks' first call in a process sets up kernels and loads their code (5-150 ms
        on a CPU), a one-time cost that the first timed act would otherwise carry."""
        if not self._warm and env is not None:
            self._warm = True
            blank = blank_observation(env.observation_space)
            if blank is not None:  # deterministic: draws nothing from a random stream
                self.agent.act(blank, deterministic=True)
        if self.critic_candidates:
            import torch

            self._generator = torch.Generator().manual_seed(self.seed)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if self.critic_candidates:
            if self._generator is None:
                self.reset()
            return self.agent.act_by_critic(obs, self.critic_candidates, generator=self._generator)
        return self.agent.act(obs, deterministic=self.deterministic)


def blank_observation(space: gym.Space) -> dict[str, np.ndarray] | None:
    """Zeros of every entry of a Dict observation space (None for any other space)."""
    if not isinstance(space, gym.spaces.Dict):
        return None
    return {key: np.zeros(sub.shape, sub.dtype) for key, sub in space.spaces.items()}


# ------------------------------------------------------------ other goal-conditioned envs
GOAL_KEYS = ("achieved_goal", "desired_goal")


def make_goal_env(env_id: str, render_mode: str | None = None) -> gym.Env:
    """A goal-conditioned Gymnasium env by id, through `gym.make`.

    `module:id` (e.g. `panda_gym:PandaReach-v3`) imports `module` first, which registers `id`.
    Goal-conditioned: a Dict observation with `achieved_goal` and `desired_goal`, and a
    `compute_reward(achieved_goal, desired_goal, info)` (the contract HER needs). Raises a
    one-line ValueError when the env cannot be made, is not goal-conditioned, or cannot render
    `render_mode`.
    """
    module = env_id.split(":", 1)[0] if ":" in env_id else None
    try:
        env = gym.make(env_id, render_mode=render_mode) if render_mode else gym.make(env_id)
    except ModuleNotFoundError as error:
        missing = getattr(error.__cause__, "name", None) or error.name or module
        raise ValueError(
            f"env {env_id!r}: cannot import {module!r} (no module named {missing!r}); install "
            "the package that registers it"
        ) from error
    except gym.error.Error as error:
        where = f" (after importing {module!r})" if module else ""
        raise ValueError(f"env {env_id!r}: {error}{where}") from error
    space = env.observation_space
    keys = space.spaces if isinstance(space, gym.spaces.Dict) else {}
    if not all(key in keys for key in GOAL_KEYS) or not hasattr(env.unwrapped, "compute_reward"):
        env.close()
        raise ValueError(
            f"env {env_id!r} is not goal-conditioned: it needs a Dict observation with "
            "'achieved_goal' and 'desired_goal' and a compute_reward method"
        )
    if render_mode and render_mode not in env.metadata.get("render_modes", []):
        env.close()
        raise ValueError(
            f"env {env_id!r} cannot render {render_mode!r} frames (its render modes: "
            f"{env.metadata.get('render_modes', [])})"
        )
    return env


def check_policy_fits(policy: Policy, env: gym.Env, env_id: str) -> None:
    """A one-line ValueError when a learned policy's networks do not read `env`'s observations
    or write its actions (baselines and other policies are not checked)."""
    agent = getattr(policy, "agent", None)
    keys = getattr(getattr(agent, "config", None), "obs_keys", None)
    if agent is None or keys is None:
        return
    spaces = env.observation_space.spaces
    missing = [key for key in keys if key not in spaces]
    if missing:
        raise ValueError(f"the policy reads {missing}, which env {env_id!r} does not observe")
    obs_dim = sum(int(np.prod(spaces[key].shape)) for key in keys)
    if obs_dim != agent.obs_dim or env.action_space.shape != (agent.action_dim,):
        raise ValueError(
            f"the policy reads {agent.obs_dim} observation values and writes "
            f"{agent.action_dim} actions; env {env_id!r} gives {obs_dim} and takes "
            f"{env.action_space.shape}"
        )
