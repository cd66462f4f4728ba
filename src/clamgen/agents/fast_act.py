"""The vision residual's deterministic action for one observation on a CPU, in plain calls.

`ResidualAgent.act(obs, deterministic=True)` for a single observation runs through here: the
operations of the module path (`encoder_input`, the multi-view encoder, `low_dim_input`,
`policy_mean`, tanh), in the same order on the agent's own parameters, read at each call (so
never stale), but as functional calls (`F.conv2d`, `F.linear`, in-place ReLU) instead of
`nn.Module` calls, without the disabled autocast context, and without the log std that a
deterministic action does not need. The actions are the module path's, bit for bit (tested for
every variant it takes).

Why: acting in an episode, the policy runs right after the env rendered its views, and the
renderer has filled the CPU's caches with its own code and data. There every Python-level layer
of the module path costs several times what it costs when repeated warm: on a 2-core AVX2 EPYC,
the shipped 3-view policy's act took 3.00 ms median between renders through the modules against
2.50 ms here, interleaved in the same episodes (`benchmarks/act_paths.py`,
`results/benchmarks/act_paths.csv`).
Like `clamgen.agents.networks.NumpyActor` for the joint policy, this exists for speed only.

Variants it does not take (a mixture actor, obstacle poses instead of images, convs in chunks
smaller than the views, a device other than the CPU) act through the modules:
`ResidualActing.build` returns None for them. Where the convs run in bf16
(`EncoderConfig.bf16_autocast` on a CPU that computes it), they do here too, under the same
autocast.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from clamgen.agents.encoders import MultiViewEncoder, bf16_enabled, to_unit_float
from clamgen.agents.networks import Actor

if TYPE_CHECKING:
    from clamgen.agents.residual import ResidualAgent

__all__ = ["ResidualActing", "run_layers"]


def run_layers(layers: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """`layers(x)` for a stack of Linear / Conv2d (zero padding) / ReLU layers, without grad,
    as functional calls (other layers are called as modules). The ReLU is applied in place, on
    the previous layer's fresh output."""
    for layer in layers:
        kind = type(layer)
        if kind is nn.Linear:
            x = F.linear(x, layer.weight, layer.bias)
        elif kind is nn.Conv2d:
            x = F.conv2d(
                x, layer.weight, layer.bias, layer.stride, layer.padding, layer.dilation,
                layer.groups,
            )  # fmt: skip
        elif kind is nn.ReLU:
            x = torch.relu_(x)
        else:
            x = layer(x)
    return x


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
        encoder = agent.critic.encoder
        if not isinstance(encoder, MultiViewEncoder) or type(agent.actor.policy) is not Actor:
            return None
        enc = encoder.config
        if enc.cpu_conv_chunk is not None and enc.cpu_conv_chunk < enc.num_views:
            return None
        convs = [m for trunk in encoder.trunks for m in trunk if isinstance(m, nn.Conv2d)]
        if any(conv.padding_mode != "zeros" for conv in convs):
            return None
        return cls(agent)

    def __call__(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Action (1, A) float32 for a batch of one observation (the low-dim keys and
        `images`, each with a leading batch axis of 1)."""
        agent = self.agent
        visual = self.visual_encoding(agent.critic.encoder, agent.encoder_input(obs))
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

    @staticmethod
    def visual_encoding(encoder: MultiViewEncoder, images: torch.Tensor) -> torch.Tensor:
        """`encoder(images)` for one observation's centre crops (1, V, C, S, S) uint8, with no
        view dropped: (1, feature_dim)."""
        cfg = encoder.config

        bf16 = cfg.bf16_autocast and bf16_enabled(images.device.type)

        def trunk_features(trunk: nn.Sequential, views: torch.Tensor) -> torch.Tensor:
            x = to_unit_float(views, torch.bfloat16 if bf16 else torch.float32)
            if cfg.channels_last:
                x = x.contiguous(memory_format=torch.channels_last)
            if not bf16:  # no autocast context where it would be off: its entry costs too
                return run_layers(trunk, x).float().flatten(1)
            with torch.autocast(x.device.type, dtype=torch.bfloat16):
                return run_layers(trunk, x).float().flatten(1)

        if cfg.share_view_weights:
            features = trunk_features(encoder.trunks[0], images.flatten(0, 1))
            features = features.reshape(1, images.shape[1], -1)
        else:
            per_view = [trunk_features(t, images[:, v]) for v, t in enumerate(encoder.trunks)]
            features = torch.stack(per_view, dim=1)
        pre_activation = encoder.project_nonzero(features).sum(1) + encoder.hidden_bias
        if encoder.mask_weight is not None:
            pre_activation = pre_activation + encoder.mask_weight.sum(0)
        encoding = F.linear(F.relu(pre_activation), encoder.head.weight, encoder.head.bias)
        if encoder.norm is not None:
            norm = encoder.norm
            encoding = F.layer_norm(
                encoding, norm.normalized_shape, norm.weight, norm.bias, norm.eps
            )
            encoding = torch.tanh(encoding)
        return encoding
