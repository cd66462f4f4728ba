"""A depth wrapper inside the env: any agent's actions pass the shield (and its planner) in
`env.step` (beyond the paper).

`DepthGuard.wrap` puts the shield around a `Policy` (anything with `act(obs)`); an agent from
another library (Stable-Baselines3's `model.predict`, a training loop of one's own) acts through
`env.step` instead. `GuardedEnv` gives it the same guard there: each step the agent's action
goes to the guard as the action of the policy it wraps, and the env applies what the guard
chose: the action itself, its shielded replacement, a step of a plan on the depth map, or a
random escape. The agent observes what the env shows but the finer depth camera a guard may
read (`fine_depth`, the guard's own sensor). The wrapper reads the env's own observations
(joints, goal, depth images), so it goes directly around a CLAMGen `ReachEnv` with RGBD views,
inside any wrapper that changes the observation layout (`clamgen.envs.wrappers.StackedViews`
for SB3):

    from clamgen.envs import ReachEnv
    from clamgen.experiments.depth_planner import HYBRID

    guard = HYBRID[2]
    env = guard.wrap_env(ReachEnv(num_obstacles=2, task_family="blocked", num_views=2,
                                  obs_mode="both", image_size=64, **guard.env_kwargs()))
    obs, _ = env.reset(seed=7_700_000)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    info["applied_action"], info["agent_action_followed"]

The reward, success and collision are those of the applied action. An RL agent trained through
it should learn from `info["applied_action"]` where it differs from its own (off-policy
learners store the action that was taken). Acting this way gives the same episodes as
`DepthGuard.wrap` around the same policy (a test).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

FOLLOWED_TOL = 1e-6
"""An applied action within this of the agent's (each joint) counts as the agent's."""


class _GivenAction:
    """The policy inside the guard: the action the agent passed to `step`."""

    def __init__(self) -> None:
        self.action: np.ndarray | None = None
        self.asked = False

    def reset(self, env: Any | None = None) -> None:
        self.action, self.asked = None, False

    def act(self, obs) -> np.ndarray:
        self.asked = True
        return self.action


class GuardedEnv(gym.Wrapper):
    """`env` (a CLAMGen `ReachEnv`, possibly in wrappers that keep its observations) whose
    actions pass `guard` (a `depth_planner.DepthGuard`): `step(action)` applies the guard's
    choice for `action` and reports it as `info["applied_action"]`, with
    `info["agent_action_followed"]` False where the guard replaced it (shielded, a plan's
    step, an escape). A one-line ValueError for an env the guard cannot read."""

    def __init__(self, env: gym.Env, guard) -> None:
        from clamgen.envs import ReachEnv

        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, ReachEnv):
            raise ValueError(f"GuardedEnv needs a CLAMGen ReachEnv, got {type(base).__name__}")
        space = env.observation_space
        keys = ["observation", "images"] + ["fine_depth"] * bool(guard.fine_depth_size)
        missing = [key for key in keys if key not in space.spaces]
        if missing or base.zoom_views:
            raise ValueError(
                "the depth guard reads the env's joints and RGBD views"
                + (" from a fine depth camera" if guard.fine_depth_size else "")
                + f": make it with num_views >= 1, obs_mode='both' and {guard.env_kwargs()} "
                f"(no zoom views); missing {missing}"
            )
        fine = space.spaces.get("fine_depth")
        if guard.fine_depth_size and fine.shape[-1] != guard.fine_depth_size:
            raise ValueError(
                f"the guard reads {guard.fine_depth_size}-pixel fine depth, the env renders "
                f"{fine.shape[-1]}: make it with {guard.env_kwargs()}"
            )
        self.guard = guard
        self._given = _GivenAction()
        self.policy = guard.wrap(self._given, base.num_views, base.image_size)
        self._obs: dict[str, np.ndarray] | None = None
        # The finer depth camera is the guard's sensor: the agent observes what it would
        # without the guard.
        self._hidden = ("fine_depth",) if guard.fine_depth_size else ()
        shown = {key: sub for key, sub in space.spaces.items() if key not in self._hidden}
        self.observation_space = gym.spaces.Dict(shown)

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.policy.reset(self.env)
        self._obs = obs
        return self._shown(obs), info

    def _shown(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {key: value for key, value in obs.items() if key not in self._hidden}

    def step(self, action):
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        given = np.asarray(action, np.float32)
        if given.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {given.shape}")
        self._given.action, self._given.asked = given, False
        applied = np.asarray(self.policy.act(self._obs), np.float32)
        obs, reward, terminated, truncated, info = self.env.step(applied)
        self._obs = obs
        followed = self._given.asked and bool(np.all(np.abs(applied - given) <= FOLLOWED_TOL))
        info = {**info, "applied_action": applied, "agent_action_followed": followed}
        return self._shown(obs), reward, terminated, truncated, info
