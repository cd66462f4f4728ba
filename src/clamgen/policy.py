"""The one interface every controller shares: a `Policy` maps an observation to an action."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    """Anything with `act(obs) -> action`: IK interpolation, RRT follower, SAC, residual SAC.

    `obs` is one environment observation (a dict of arrays); the action is (6,) in [-1, 1].
    `reset` is called at the start of every episode (stateful policies plan there).
    """

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...

    def reset(self, env: Any | None = None) -> None: ...
