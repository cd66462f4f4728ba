"""Auxiliary losses of stage 2 (paper, "Learned 3D fusion for Obstacle-Avoidance").

- CURL's contrastive loss (Srinivas et al., 2020): the query is the online encoding of one random
  crop of an observation, the positive key the momentum (EMA) encoder's encoding of another crop
  of the same observation, the negatives the keys of the other observations in the batch;
  similarity ``q^T W k`` with a learned bilinear W; InfoNCE = cross-entropy over the batch.
- The across-view term: the encodings of different camera views of the same scene are
  positives, those of views of other scenes negatives. We use the pairwise form of Contrastive
  Multiview Coding (Tian et al., 2019): for every ordered pair of views i != j, view i of scene b
  is a query whose positive key is view j of scene b and whose negatives are view j of the other
  scenes; the loss averages the V (V - 1) InfoNCE terms. The per-view embeddings are
  :meth:`clamgen.agents.encoders.MultiViewEncoder.single_view_encodings`.
- The collision-dynamics loss: from the latent z_t and the action a_t, predict whether the step
  collides; binary cross-entropy on the logit, with an optional positive-class weight because
  collisions are a minority of steps.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import nn

from clamgen.agents.networks import mlp
from clamgen.agents.sac import soft_update

__all__ = [
    "AUX_LOSSES",
    "AcrossViewLoss",
    "AuxDims",
    "AuxInputs",
    "AuxLoss",
    "AuxLossConfig",
    "CURLHead",
    "CollisionHead",
    "CollisionLoss",
    "InstanceContrastiveLoss",
    "StateLoss",
    "across_view_loss",
    "bilinear_logits",
    "build_aux_losses",
    "collision_loss",
    "curl_loss",
    "make_momentum_copy",
    "momentum_update",
    "register_aux_loss",
]


@dataclass(frozen=True)
class AuxLossConfig:
    """Weights and sizes of the stage-2 auxiliary losses (each weight 0 switches its term off)."""

    curl_weight: float = 1.0
    """Weight of CURL's instance contrastive loss (crop vs crop of one observation)."""
    across_view_weight: float = 1.0
    """Weight of the across-view contrastive term (view vs view of one scene)."""
    collision_weight: float = 1.0
    """Weight of the collision-prediction loss."""
    state_weight: float = 0.0
    """Weight of a regression of the normalised joints and goal from the visual encoding
    (privileged information, used in training only; not in the paper). It teaches an
    image-only encoder where the arm and the target are; 0 switches it off."""
    collision_pos_weight: float | None = None
    """Factor on the loss of colliding steps (BCE ``pos_weight``); about (non-colliding steps) /
    (colliding steps) balances the classes; None weighs both classes alike."""
    collision_hidden_sizes: tuple[int, ...] = (256,)
    """Hidden ReLU layer widths of the collision head."""
    encoder_momentum_tau: float = 0.05
    """EMA rate of the key encoder: target <- (1 - tau) target + tau online (CURL's 0.05)."""
    extra_weights: dict[str, float] = field(default_factory=dict)
    """Weights of further registered auxiliary losses (`register_aux_loss`), by name."""


def bilinear_logits(query: torch.Tensor, key: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Similarity ``q_b^T W k_c`` for every query b and key c, with each row's max subtracted.

    Subtracting the row max leaves the softmax unchanged and keeps exp() finite (CURL does the
    same).

    Args:
        query: (..., B, D) float.
        key: (..., B, D) float.
        weight: (D, D) float, the bilinear form W.

    Returns:
        (..., B, B) float, row b = query b against every key.
    """
    logits = (query @ weight) @ key.transpose(-1, -2)
    return logits - logits.amax(-1, keepdim=True).detach()


def curl_loss(query_z: torch.Tensor, key_z: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """CURL's InfoNCE loss; the positive of query b is key b (the diagonal).

    Args:
        query_z: (B, D) float, online encodings of one crop of each observation.
        key_z: (B, D) float, encodings of another crop of the same observations, normally from
            the momentum encoder (no gradient); gradients reach ``weight`` and ``query_z``.
        weight: (D, D) float, the bilinear form W.

    Returns:
        Scalar float: mean cross-entropy over the B queries; log(B) for uninformative logits.
    """
    logits = bilinear_logits(query_z, key_z, weight)
    labels = torch.arange(len(logits), device=logits.device)
    return F.cross_entropy(logits, labels)


def across_view_loss(
    query_views: torch.Tensor, key_views: torch.Tensor, weight: torch.Tensor
) -> torch.Tensor:
    """Across-view InfoNCE: views of one scene are positives, other scenes' views negatives.

    For each ordered view pair (i, j), i != j, query ``query_views[b, i]`` is scored against
    ``key_views[c, j]`` for every scene c of the batch; the positive is c = b. The loss is the
    mean over the B * V * (V - 1) queries.

    Args:
        query_views: (B, V, D) float, per-view embeddings (online encoder).
        key_views: (B, V, D) float, per-view embeddings of the same scenes (momentum encoder for
            keys without gradient, or ``query_views`` itself for a symmetric loss).
        weight: (D, D) float, the bilinear form W.

    Returns:
        Scalar float; 0 (with a graph) when V = 1, which has no view pair.
    """
    batch, num_views = query_views.shape[:2]
    if num_views < 2:
        return query_views.sum() * 0.0 + weight.sum() * 0.0
    # (V, B, D) queries against (V, B, D) keys: logits[i, j, b, c] = q[b, i]^T W k[c, j].
    queries = (query_views @ weight).transpose(0, 1)
    keys = key_views.transpose(0, 1)
    logits = torch.einsum("ibd,jcd->ijbc", queries, keys)
    off_diagonal = ~torch.eye(num_views, dtype=torch.bool, device=logits.device)
    logits = logits[off_diagonal]  # (V (V - 1), B, B)
    logits = logits - logits.amax(-1, keepdim=True).detach()
    labels = torch.arange(batch, device=logits.device).expand(len(logits), batch)
    return F.cross_entropy(logits.flatten(0, 1), labels.flatten())


class CURLHead(nn.Module):
    """Bilinear forms of the two contrastive terms: W for CURL's crop-vs-crop InfoNCE and, when
    ``across_view``, a separate W for the view-vs-view term.

    Both start at the identity, so the first logits are plain dot products of the encodings
    (CURL starts from a random W; the identity gives a useful signal from the first update).
    """

    def __init__(self, feature_dim: int, across_view: bool = True) -> None:
        super().__init__()
        self.W = nn.Parameter(torch.eye(feature_dim))
        self.W_view: nn.Parameter | None = None
        if across_view:
            self.W_view = nn.Parameter(torch.eye(feature_dim))

    def instance_loss(self, query_z: torch.Tensor, key_z: torch.Tensor) -> torch.Tensor:
        """:func:`curl_loss` with this head's W: query (B, D), key (B, D) -> scalar."""
        return curl_loss(query_z, key_z, self.W)

    def across_view_loss(self, query_views: torch.Tensor, key_views: torch.Tensor) -> torch.Tensor:
        """:func:`across_view_loss` with this head's W_view: (B, V, D) twice -> scalar."""
        if self.W_view is None:
            raise RuntimeError("this CURLHead was built with across_view=False")
        return across_view_loss(query_views, key_views, self.W_view)

    def forward(self, query_z: torch.Tensor, key_z: torch.Tensor) -> torch.Tensor:
        """Same as :meth:`instance_loss`."""
        return self.instance_loss(query_z, key_z)


def make_momentum_copy(module: nn.Module) -> nn.Module:
    """A frozen deep copy of ``module`` to serve as its momentum (EMA) target; keep it in eval
    use only and move it with :func:`momentum_update`."""
    return copy.deepcopy(module).requires_grad_(False)


@torch.no_grad()
def momentum_update(target: nn.Module, online: nn.Module, tau: float) -> None:
    """EMA step in place: every target parameter <- (1 - tau) target + tau online.

    Buffers (none in the encoders here) are copied as they are. Same convention as
    :func:`clamgen.agents.sac.soft_update`, whose tau is the critic's.
    """
    if not 0.0 <= tau <= 1.0:
        raise ValueError(f"tau must be in [0, 1], got {tau}")
    soft_update(target, online, tau)
    for target_buffer, online_buffer in zip(target.buffers(), online.buffers(), strict=True):
        target_buffer.copy_(online_buffer)


class CollisionHead(nn.Module):
    """Logit that executing action a_t from latent z_t collides (paper's collision dynamics).

    An MLP on ``concat(z_t, a_t)``; ``sigmoid(logit)`` is the predicted collision probability.
    """

    def __init__(self, latent_dim: int, action_dim: int, hidden_sizes: tuple[int, ...]) -> None:
        super().__init__()
        self.net = mlp(latent_dim + action_dim, hidden_sizes, 1)

    def forward(self, latent: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Logits (B,) float from latent (B, Dz) and action (B, A) in [-1, 1]."""
        return self.net(torch.cat([latent, action], dim=-1)).squeeze(-1)


def collision_loss(
    logits: torch.Tensor, collided: torch.Tensor, pos_weight: float | None = None
) -> torch.Tensor:
    """Binary cross-entropy of collision logits, mean over the batch.

    Args:
        logits: (B,) float from :class:`CollisionHead`.
        collided: (B,) bool or float in {0, 1}: whether the step reported a collision.
        pos_weight: factor on the loss of colliding steps (class imbalance); None means 1.

    Returns:
        Scalar float.
    """
    weight = None
    if pos_weight is not None:
        weight = torch.tensor(pos_weight, dtype=logits.dtype, device=logits.device)
    return F.binary_cross_entropy_with_logits(logits, collided.to(logits.dtype), pos_weight=weight)


# --------------------------------------------------------------------------------------------
# Auxiliary losses as the stage-2 agent uses them: each owns its head, its weight and its
# metrics. A new loss is one subclass registered with `register_aux_loss` plus its weight in
# `AuxLossConfig.extra_weights`; the agent then builds it, trains its parameters with the
# critic's optimiser, moves it to the device and keeps it in its state dict.


@dataclass(frozen=True)
class AuxDims:
    """Sizes an auxiliary loss builds its head from."""

    feature_dim: int
    """Size of the visual encoding (B, Dv)."""
    latent_dim: int
    """Size of the critic's fused latent: visual encoding + low-dim encoding (B, Dz)."""
    action_dim: int
    """Size A of an action."""
    state_dim: int
    """Size of the true low-dim state: joints (6) + goal (3)."""
    num_views: int
    """Camera views V (0 for the privileged obstacle-pose input)."""


class AuxInputs:
    """What an auxiliary loss may read in one update (B = batch size).

    Attributes:
        latent: (B, Dz) the critic's fused latent of the query crop (gradients reach the
            encoder when the critic trains it).
        visual: (B, Dv) the visual encoding of the query crop, with gradients to the encoder.
        action: (B, A) the batch's actions in [-1, 1].
        collided: (B,) float in {0, 1}: whether the step reported a collision.
        state: (B, 9) the true normalised joints + goal (privileged; training only).
    The contrastive terms read the per-view encodings of the query crop and the momentum
    encoder's encodings of a second crop (:attr:`key_merged`, :attr:`key_views`), computed
    on first use and shared between the terms.
    """

    def __init__(
        self,
        latent: torch.Tensor,
        visual: torch.Tensor,
        action: torch.Tensor,
        collided: torch.Tensor,
        state: torch.Tensor,
        encoder: nn.Module | None = None,
        query_projections: torch.Tensor | None = None,
        key_encoder: nn.Module | None = None,
        key_images: Callable[[], torch.Tensor] | None = None,
    ) -> None:
        self.latent, self.visual, self.action = latent, visual, action
        self.collided, self.state = collided, state
        self._encoder, self._query_projections = encoder, query_projections
        self._key_encoder, self._key_images = key_encoder, key_images

    @functools.cached_property
    def query_merged(self) -> torch.Tensor:
        """(B, Dv) online encoding of the query crop with every view kept."""
        return self._encoder.merge_projected(self._query_projections)

    @functools.cached_property
    def query_views(self) -> torch.Tensor:
        """(B, V, Dv) online encoding of each view of the query crop alone."""
        return self._encoder.single_views_projected(self._query_projections)

    @functools.cached_property
    def _key_projections(self) -> torch.Tensor:
        with torch.no_grad():
            return self._key_encoder.project(self._key_encoder.conv_trunk(self._key_images()))

    @functools.cached_property
    def key_merged(self) -> torch.Tensor:
        """(B, Dv) momentum encoding of a second crop of the same images (no gradient)."""
        with torch.no_grad():
            return self._key_encoder.merge_projected(self._key_projections)

    @functools.cached_property
    def key_views(self) -> torch.Tensor:
        """(B, V, Dv) momentum encoding of each view of the second crop (no gradient)."""
        with torch.no_grad():
            return self._key_encoder.single_views_projected(self._key_projections)


class AuxLoss(nn.Module):
    """An auxiliary loss of stage 2: its head's parameters, its weight, its metrics.

    Subclasses set `name` (the metric is `train/{name}_loss`), build their head in
    `__init__(dims, config)` and compute `forward(inputs) -> (loss, extra metrics)`.
    """

    name: ClassVar[str]
    weight_field: ClassVar[str | None] = None
    """The `AuxLossConfig` field holding a built-in loss's weight; None: `extra_weights`."""
    needs_images: ClassVar[bool] = False
    """Only built for image observations (the contrastive terms)."""
    in_policy: ClassVar[bool] = False
    """Its head is kept in exported policy files (it is used at inference, not only in
    training)."""

    def __init__(self, dims: AuxDims, config: AuxLossConfig) -> None:
        super().__init__()
        self.weight = self.weight_in(config)

    @classmethod
    def weight_in(cls, config: AuxLossConfig) -> float:
        """This loss's weight in `config`: its own field, or its entry in `extra_weights`."""
        if cls.weight_field is not None:
            return float(getattr(config, cls.weight_field))
        return float(config.extra_weights.get(cls.name, 0.0))

    @classmethod
    def configured(cls, config: AuxLossConfig, dims: AuxDims) -> bool:
        """Whether an agent with this config and these inputs has the loss at all (built-in
        losses always, others when `extra_weights` names them; image terms need images)."""
        named = cls.weight_field is not None or cls.name in config.extra_weights
        return named and (dims.num_views > 0 or not cls.needs_images)

    def forward(self, inputs: AuxInputs) -> tuple[torch.Tensor, dict[str, float]]:
        raise NotImplementedError


AUX_LOSSES: dict[str, type[AuxLoss]] = {}
"""Every registered auxiliary loss by name, in registration order (the order of the sum)."""


def register_aux_loss(cls: type[AuxLoss]) -> type[AuxLoss]:
    """Class decorator: make `cls` available to the stage-2 agent under `cls.name`."""
    if not getattr(cls, "name", ""):
        raise ValueError(f"{cls.__name__} needs a class attribute `name`")
    AUX_LOSSES[cls.name] = cls
    return cls


def build_aux_losses(config: AuxLossConfig, dims: AuxDims) -> nn.ModuleDict:
    """The configured auxiliary losses of an agent, by name."""
    unknown = set(config.extra_weights) - set(AUX_LOSSES)
    if unknown:
        raise ValueError(
            f"unknown auxiliary losses {sorted(unknown)} in aux.extra_weights; registered: "
            f"{sorted(AUX_LOSSES)}"
        )
    configured = {n: cls for n, cls in AUX_LOSSES.items() if cls.configured(config, dims)}
    return nn.ModuleDict({name: cls(dims, config) for name, cls in configured.items()})


@register_aux_loss
class CollisionLoss(AuxLoss):
    """The paper's collision dynamics: from z_t and a_t, predict whether the step collides."""

    name = "collision"
    weight_field = "collision_weight"

    def __init__(self, dims: AuxDims, config: AuxLossConfig) -> None:
        super().__init__(dims, config)
        self.head = CollisionHead(dims.latent_dim, dims.action_dim, config.collision_hidden_sizes)
        self.pos_weight = config.collision_pos_weight

    def forward(self, inputs: AuxInputs) -> tuple[torch.Tensor, dict[str, float]]:
        logits = self.head(inputs.latent, inputs.action)
        loss = collision_loss(logits, inputs.collided, self.pos_weight)
        predicted = (logits.detach() > 0).float()
        accuracy = (predicted == inputs.collided).float().mean().item()
        return loss, {"train/collision_accuracy": accuracy}


@register_aux_loss
class StateLoss(AuxLoss):
    """Regression of the normalised joints + goal from the visual encoding (ours, training
    only): teaches an image-only encoder where the arm and the target are. The head is also
    what `ResidualAgent.predict_state` and encoder pretraining use."""

    name = "state"
    weight_field = "state_weight"
    in_policy = True

    def __init__(self, dims: AuxDims, config: AuxLossConfig) -> None:
        super().__init__(dims, config)
        self.head = mlp(dims.feature_dim, (256,), dims.state_dim)

    def regression(self, visual: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """MSE of the head's (B, 9) prediction from `visual` (B, Dv) to `state`."""
        return F.mse_loss(self.head(visual), state)

    def forward(self, inputs: AuxInputs) -> tuple[torch.Tensor, dict[str, float]]:
        return self.regression(inputs.visual, inputs.state), {}


class _BilinearContrastiveLoss(AuxLoss):
    """A contrastive term with its own bilinear form W, started at the identity (the first
    logits are dot products; see CURLHead)."""

    needs_images = True

    def __init__(self, dims: AuxDims, config: AuxLossConfig) -> None:
        super().__init__(dims, config)
        self.W = nn.Parameter(torch.eye(dims.feature_dim))


@register_aux_loss
class InstanceContrastiveLoss(_BilinearContrastiveLoss):
    """CURL's crop-vs-crop InfoNCE: the query crop's online encoding against the momentum
    encoding of another crop of the same images."""

    name = "curl"
    weight_field = "curl_weight"

    def forward(self, inputs: AuxInputs) -> tuple[torch.Tensor, dict[str, float]]:
        return curl_loss(inputs.query_merged, inputs.key_merged, self.W), {}


@register_aux_loss
class AcrossViewLoss(_BilinearContrastiveLoss):
    """The paper's across-view contrastive term: views of one scene are positives."""

    name = "across_view"
    weight_field = "across_view_weight"

    @classmethod
    def configured(cls, config: AuxLossConfig, dims: AuxDims) -> bool:
        return dims.num_views > 1  # one view has no pair of views

    def forward(self, inputs: AuxInputs) -> tuple[torch.Tensor, dict[str, float]]:
        return across_view_loss(inputs.query_views, inputs.key_views, self.W), {}
