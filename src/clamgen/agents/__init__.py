"""Learning agents: stage-1 goal-conditioned SAC (paper, "Arm Motion Generation")."""

from clamgen.agents.networks import Actor, EnsembleCritic, NumpyActor, RunningNormalizer
from clamgen.agents.sac import NonFiniteLossError, SACAgent, SACConfig, flatten_obs

__all__ = [
    "Actor",
    "EnsembleCritic",
    "NonFiniteLossError",
    "NumpyActor",
    "RunningNormalizer",
    "SACAgent",
    "SACConfig",
    "flatten_obs",
]
