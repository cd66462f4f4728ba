"""The vision residual's deterministic action for one observation on a CPU, in plain calls.

`ResidualAgent.act(obs, deterministic=True)` for a single observation runs through here: the
operations of the module path (`encoder_input`, the multi-view encoder, `low_dim_input`,
`policy_mean`, tanh), in the same order on the agent's own parameters, read at each call (so
never stale). The encoder runs its convs as plain calls whenever no gradient is tracked
(`MultiViewEncoder._trunk_features`, `clamgen.agents.networks.run_layers`); here the actor's
and the base's layers run that way too (`F.linear`, in-place ReLU instead of `nn.Module`
calls), without the log std that a deterministic action does not need. The actions are the
module path's, bit for bit (tested for every variant it takes).

Why: acting in an episode, the policy runs right after the env rendered its views, and the
renderer has filled the CPU's caches with its own code and data. There every Python-level layer
of the module path costs several times what it costs when repeated warm, as much as a small
conv (measured on a 2-core AVX2 EPYC: `benchmarks/act_paths.py`,
`results/benchmarks/act_paths.csv`, and session 57 in
`results/benchmarks/act_latency_runs/README.md`). Like `clamgen.agents.networks.NumpyActor`
for the joint policy, this exists for speed only.

Variants it does not take (a mixture actor, obstacle poses instead of images, a device other
than the CPU) act through the modules: `ResidualActing.build` returns None for them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F

from clamgen.agents.networks import Actor, run_layers

if TYPE_CHECKING:
    from clamgen.agents.residual import ResidualAgent

__all__ = ["ResidualActing"]


class ResidualActing:
    """`agent.act(obs, deterministic=True)` for a batch of one observation (the module
    docstring says how and why). Build it with `build`; call it under inference mode."""

    def __init__(self, agent: ResidualAgent) -> None:
        self.agent = agent

    @classmethod
    def build(cls, agent: ResidualAgent) -> ResidualActing | None:
        """The fast path for `agent`, or None where it acts through its modules only."""
        cfg = agent.config
        if agent.device.type != "cpu" or cfg.obs_source != "images":
            return None
        if type(agent.actor.policy) is not Actor:
            return None
        return cls(agent)

    def __call__(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Action (1, A) float32 for a batch of one observation (the low-dim keys and
        `images`, each with a leading batch axis of 1)."""
        agent = self.agent
        visual = agent.critic.encoder(agent.encoder_input(obs))  # plain calls without grad
        low_dim = agent.low_dim_input(obs)
        actor = agent.actor
        actor_low = low_dim if agent.config.use_low_dim else torch.zeros_like(low_dim)
        features = torch.cat([visual, F.relu(actor.low_dim.dense(actor_low))], dim=-1)
        num_actions = agent.action_dim
        mean = run_layers(actor.policy.trunk, features)[..., :num_actions]
        if agent.config.residual:  # the base reads the true joints + goal as the actor sees them
            base_in = actor_low[..., : agent.base.obs_dim]
            mean = mean + run_layers(agent.base_actor.trunk, base_in)[..., :num_actions]
        return torch.tanh(mean).cpu().numpy()
