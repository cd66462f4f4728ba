"""The one interface every controller shares: a `Policy` maps an observation to an action."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from clamgen.robot import ur5


@runtime_checkable
class Policy(Protocol):
    """Anything with `act(obs) -> action`: IK interpolation, RRT follower, SAC, residual SAC.

    `obs` is one environment observation (a dict of arrays); the action is (6,) in [-1, 1].
    `reset` is called at the start of every episode (stateful policies plan there).
    """

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...

    def reset(self, env: Any | None = None) -> None: ...


class HoldStill:
    """The arm holds still: a zero joint command every step (no policy inside a wrapper that
    acts by itself, such as the `depth-rrt-*` baselines' planner on the depth map)."""

    def reset(self, env: Any | None = None) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.zeros(ur5.NUM_JOINTS, np.float32)


class ScaledPolicy:
    """`policy` acting with its actions multiplied by `scale` (0 < scale <= 1): each step in
    the same direction, `scale` as long (the env moves each joint by the action times
    `MAX_JOINT_DELTA_RAD`), so the arm moves more slowly and reaches in more steps. A test-time
    setting of any policy (`clamgen eval --action-scale`); 1 acts as trained."""

    def __init__(self, policy: Policy, scale: float) -> None:
        if not 0.0 < scale <= 1.0:
            raise ValueError(f"action scale must be in (0, 1], got {scale}")
        self.policy = policy
        self.scale = float(scale)

    @property
    def agent(self):
        """The wrapped policy's agent, if it has one (what its networks observe)."""
        return getattr(self.policy, "agent", None)

    def reset(self, env: Any | None = None) -> None:
        self.policy.reset(env)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.float32(self.scale) * np.asarray(self.policy.act(obs), np.float32)

    def skipped(self, steps: int) -> None:
        """Passed on to the wrapped policy, if it listens (`evaluate.run_episode(real_time=True)`:
        a planner that counts the steps it did not see)."""
        if hasattr(self.policy, "skipped"):
            self.policy.skipped(steps)
