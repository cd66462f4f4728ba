"""Small networks for SAC: tanh-Gaussian actor, fused twin critic, observation normaliser.

The paper's "Arm Motion Generation" section builds on SAC with the clipped double-Q trick; its
controller module is a few ReLU dense layers. These modules take already flattened (and, for
images, already encoded) features, so the stage-2 residual agent can reuse them on top of its
own encoder. :class:`NumpyActor` is an inference-only copy of the actor's forward pass in numpy
for sub-0.1 ms actions at batch 1 on a CPU, where torch's per-op overhead dominates.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def mlp(input_dim: int, hidden_sizes: tuple[int, ...], output_dim: int) -> nn.Sequential:
    """Linear-ReLU stack: input_dim -> hidden_sizes... -> output_dim (no output activation)."""
    layers: list[nn.Module] = []
    for size in hidden_sizes:
        layers += [nn.Linear(input_dim, size), nn.ReLU()]
        input_dim = size
    layers.append(nn.Linear(input_dim, output_dim))
    return nn.Sequential(*layers)


def run_layers(layers: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """`layers(x)` without grad, its Linear, Conv2d (zero padding) and ReLU layers as plain
    functional calls, any other layer as a module call: the same values without the modules'
    per-call overhead, which dominates small layers acting between an env's renders
    (`clamgen.agents.fast_act`). The ReLU is applied in place, on the previous layer's fresh
    output."""
    for layer in layers:
        kind = type(layer)
        if kind is nn.Linear:
            x = F.linear(x, layer.weight, layer.bias)
        elif kind is nn.Conv2d and layer.padding_mode == "zeros":
            x = F.conv2d(
                x, layer.weight, layer.bias, layer.stride, layer.padding, layer.dilation,
                layer.groups,
            )  # fmt: skip
        elif kind is nn.ReLU:
            x = torch.relu_(x)
        else:
            x = layer(x)
    return x


def tanh_gaussian_sample(
    mean: torch.Tensor, log_std: torch.Tensor, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparameterised sample tanh(mean + std * eps), (B, A) in (-1, 1), and its exact
    log-probability (B,) under the tanh-squashed Gaussian."""
    noise = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
    pre_squash = mean + log_std.exp() * noise
    # log N(u; mean, std) - log|d tanh(u)/du|, with log(1 - tanh(u)^2) written stably as
    # 2 (log 2 - u - softplus(-2u)).
    gaussian = -0.5 * noise.pow(2) - log_std - _LOG_SQRT_2PI
    squash = 2.0 * (math.log(2.0) - pre_squash - F.softplus(-2.0 * pre_squash))
    return torch.tanh(pre_squash), (gaussian - squash).sum(-1)


class _TanhGaussianPolicy(nn.Module):
    """What the actors share: `forward` gives the pre-squash mean and log std (B, A) of the
    action to take, bounded smoothly to `log_std_bounds` (as in DrQ-v2's SAC ancestor, which
    keeps exp() finite); sampling and the deterministic action follow from it."""

    log_std_bounds: tuple[float, float]

    def bounded_log_std(self, raw_log_std: torch.Tensor) -> torch.Tensor:
        low, high = self.log_std_bounds
        return low + 0.5 * (high - low) * (torch.tanh(raw_log_std) + 1.0)

    def sample(
        self, features: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Reparameterised action (B, A) in (-1, 1) and its log-probability (B,)."""
        return tanh_gaussian_sample(*self(features), generator)

    def mode(self, features: torch.Tensor) -> torch.Tensor:
        """Deterministic action tanh(mean), (B, A)."""
        return torch.tanh(self(features)[0])


class Actor(_TanhGaussianPolicy):
    """Tanh-squashed diagonal Gaussian policy ``pi(a | s, g)`` over actions in [-1, 1]^A."""

    def __init__(
        self,
        input_dim: int,
        action_dim: int,
        hidden_sizes: tuple[int, ...],
        log_std_bounds: tuple[float, float],
    ) -> None:
        super().__init__()
        self.action_dim = action_dim
        self.log_std_bounds = log_std_bounds
        self.trunk = mlp(input_dim, hidden_sizes, 2 * action_dim)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pre-squash mean and log standard deviation, each (B, A), from features (B, D)."""
        mean, raw_log_std = self.trunk(features).chunk(2, dim=-1)
        return mean, self.bounded_log_std(raw_log_std)


class MixtureActor(_TanhGaussianPolicy):
    """``components`` candidate actions and a choice among them, for behaviour cloning of a
    teacher whose actions are multimodal (beyond the paper). Where an obstacle can be passed on
    either side, a teacher labels nearby states with either side; one mean regressed on both
    learns their average, which runs into the obstacle. Here each label trains only the
    candidate nearest to it (multiple-choice learning, "winner takes all": Guzman-Rivera et al.
    2012, Lee et al. 2016), so the candidates settle on different sides, and a choice head
    learns which candidate wins where. A mixture's likelihood would do the same in principle,
    but one wide component covering both sides is a local optimum it often stops in.

    It acts as :class:`Actor` does, with the chosen candidate: `forward` gives its mean and log
    std (each candidate has one, for sampling), so acting needs no other change."""

    def __init__(
        self,
        input_dim: int,
        action_dim: int,
        hidden_sizes: tuple[int, ...],
        log_std_bounds: tuple[float, float],
        components: int,
        others_weight: float = 0.05,
    ) -> None:
        super().__init__()
        self.action_dim = action_dim
        self.num_components = components
        self.log_std_bounds = log_std_bounds
        self.others_weight = others_weight
        """Share of the loss spread over the losing candidates (relaxed winner-takes-all), so
        that no candidate is left where no label ever reaches it."""
        # Outputs: K means (K * A), K raw log stds (K * A), K choice logits (K).
        self.trunk = mlp(input_dim, hidden_sizes, components * (2 * action_dim + 1))

    def components(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Means and log stds (B, K, A) and choice logits (B, K) from features (B, D)."""
        k, a = self.num_components, self.action_dim
        out = self.trunk(features)
        mean = out[..., : k * a].unflatten(-1, (k, a))
        raw_log_std = out[..., k * a : 2 * k * a].unflatten(-1, (k, a))
        return mean, self.bounded_log_std(raw_log_std), out[..., 2 * k * a :]

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pre-squash mean and log std (B, A) of the chosen candidate (`sample` and `mode`
        act with it)."""
        mean, log_std, logits = self.components(features)
        rows, best = torch.arange(len(logits), device=logits.device), logits.argmax(-1)
        return mean[rows, best], log_std[rows, best]

    def imitation_loss(self, features: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Squared error (mean over action dimensions) of the candidate nearest to each
        pre-squash target (B, A), `others_weight` of it spread over the other candidates, plus
        the cross-entropy of the choice head against that nearest candidate."""
        mean, _, logits = self.components(features)
        errors = (target[:, None, :] - mean).pow(2).mean(-1)  # (B, K)
        winner = errors.detach().argmin(-1)
        nearest = errors.gather(1, winner[:, None]).squeeze(1)
        others = (errors.sum(-1) - nearest) / max(self.num_components - 1, 1)
        regression = (1 - self.others_weight) * nearest + self.others_weight * others
        return regression.mean() + F.cross_entropy(logits, winner)


class EnsembleLinear(nn.Module):
    """``num_members`` independent linear layers applied in one batched matmul.

    Maps (E, B, in_features) to (E, B, out_features); initialised like ``nn.Linear``.
    """

    def __init__(self, num_members: int, in_features: int, out_features: int) -> None:
        super().__init__()
        bound = 1.0 / math.sqrt(in_features)
        self.weight = nn.Parameter(
            torch.empty(num_members, in_features, out_features).uniform_(-bound, bound)
        )
        self.bias = nn.Parameter(torch.empty(num_members, 1, out_features).uniform_(-bound, bound))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


class EnsembleCritic(nn.Module):
    """``num_q`` Q-functions ``Q(s, g, a)`` evaluated in one pass (clipped double-Q when 2).

    Every layer is an :class:`EnsembleLinear`; the input is broadcast to the members without a
    copy, and activations stay contiguous (num_q, B, width) so each layer is one batched matmul.
    """

    def __init__(
        self, input_dim: int, action_dim: int, hidden_sizes: tuple[int, ...], num_q: int = 2
    ) -> None:
        super().__init__()
        self.num_q = num_q
        sizes = [input_dim + action_dim, *hidden_sizes, 1]
        self.layers = nn.ModuleList(
            EnsembleLinear(num_q, sizes[i], sizes[i + 1]) for i in range(len(sizes) - 1)
        )

    def forward(self, features: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q-values (num_q, B) from features (B, D) and actions (B, A)."""
        x = torch.cat([features, action], dim=-1)
        hidden = x.expand(self.num_q, *x.shape)
        for layer in self.layers[:-1]:
            hidden = F.relu(layer(hidden))
        return self.layers[-1](hidden).squeeze(-1)


class RunningNormalizer(nn.Module):
    """Per-feature running mean/std normalisation, clipped to [-clip, clip].

    Goal-conditioned SAC/HER normalises its inputs (Andrychowicz et al., 2017): joint angles
    (radians, spread over +-2pi) and goals (metres, a 0.4 m box) differ in scale by an order of
    magnitude. Statistics are merged batch by batch (Chan et al.'s parallel variance) in float64.
    """

    count: torch.Tensor
    mean: torch.Tensor
    sq_dev_sum: torch.Tensor
    std: torch.Tensor

    def __init__(self, num_features: int, clip: float, min_std: float = 1e-2) -> None:
        super().__init__()
        self.clip = clip
        self.min_std = min_std
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("mean", torch.zeros(num_features, dtype=torch.float64))
        self.register_buffer("sq_dev_sum", torch.zeros(num_features, dtype=torch.float64))
        # float32 copies used by forward() and by NumpyActor (which views them).
        self.register_buffer("mean32", torch.zeros(num_features))
        self.register_buffer("std", torch.ones(num_features))

    @torch.no_grad()
    def update(self, features: torch.Tensor) -> None:
        """Merge a batch (B, D) into the statistics."""
        batch = features.to(torch.float64)
        batch_count = float(len(batch))
        batch_mean = batch.mean(0)
        delta = batch_mean - self.mean
        total = self.count + batch_count
        self.mean += delta * (batch_count / total)
        self.sq_dev_sum += (batch - batch_mean).pow(2).sum(0) + delta.pow(2) * (
            self.count * batch_count / total
        )
        self.count.copy_(total)
        self.mean32.copy_(self.mean)
        self.std.copy_((self.sq_dev_sum / self.count).sqrt().clamp_min(self.min_std))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return ((features - self.mean32) / self.std).clamp(-self.clip, self.clip)


class NumpyActor:
    """The actor's forward pass in numpy, sharing memory with the torch parameters.

    The arrays are views of the (CPU) parameter tensors, which the optimiser and
    ``load_state_dict`` update in place, so this never goes stale. Rebuild it if parameters are
    replaced rather than updated.
    """

    def __init__(self, actor: Actor, normalizer: RunningNormalizer | None) -> None:
        linears = [m for m in actor.trunk if isinstance(m, nn.Linear)]
        # (in, out) views of torch's (out, in) weights, so that x @ w works for x (D,) or (B, D).
        weights = [layer.weight.detach().numpy().T for layer in linears]
        biases = [layer.bias.detach().numpy() for layer in linears]
        self._hidden = list(zip(weights[:-1], biases[:-1], strict=True))
        a = actor.action_dim
        self._mean_w, self._mean_b = weights[-1][:, :a], biases[-1][:a]
        self._log_std_w, self._log_std_b = weights[-1][:, a:], biases[-1][a:]
        self._log_std_bounds = actor.log_std_bounds
        self._norm = None
        if normalizer is not None:
            self._norm = (
                normalizer.mean32.numpy(),
                normalizer.std.numpy(),
                normalizer.clip,
            )

    def __call__(
        self, features: np.ndarray, deterministic: bool, rng: np.random.Generator
    ) -> np.ndarray:
        """Action (A,) or (B, A) float32 for float32 features (D,) or (B, D)."""
        x = features
        if self._norm is not None:
            mean, std, clip = self._norm
            x = np.clip((x - mean) / std, -clip, clip)
        for weight, bias in self._hidden:
            x = x @ weight + bias
            np.maximum(x, 0.0, out=x)
        pre_squash = x @ self._mean_w + self._mean_b
        if not deterministic:
            low, high = self._log_std_bounds
            raw = np.tanh(x @ self._log_std_w + self._log_std_b)
            std = np.exp(low + 0.5 * (high - low) * (raw + 1.0))
            pre_squash += std * rng.standard_normal(pre_squash.shape, dtype=np.float32)
        return np.tanh(pre_squash)
