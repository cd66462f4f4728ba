"""Goal-conditioned soft actor-critic: stage 1 of CLAMGen (paper, "Arm Motion Generation").

SAC (Haarnoja et al., 2018) with clipped double-Q, Polyak-averaged target critic and a learned
temperature, on a flat vector of observation keys (joint angles and desired goal for the joint
policy). The critic loss is the paper's Eq. (critic_loss) with target
``r + gamma (1 - done) (min_i Q_target_i(s', a') - alpha log pi(a' | s'))``; the actor maximises
``min_i Q_i(s, a) - alpha log pi(a | s)``. ``update()`` reads as the recipe: normalise, critic,
actor and temperature, soft update.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces

from clamgen.agents.networks import Actor, EnsembleCritic, NumpyActor, RunningNormalizer
from clamgen.replay.episode import Batch

__all__ = [
    "Actor",
    "EnsembleCritic",
    "NonFiniteLossError",
    "SACAgent",
    "SACConfig",
    "check_sac_settings",
    "finite_value",
    "flatten_obs",
    "soft_update",
]


@dataclass(frozen=True)
class SACConfig:
    """Soft actor-critic settings for the stage-1 joint policy."""

    obs_keys: tuple[str, ...] = ("observation", "desired_goal")
    """Observation keys concatenated, in this order, into the network input; each a vector."""
    hidden_sizes: tuple[int, ...] = (256, 256)
    """Hidden layer widths of the actor and of each Q-network (ReLU)."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the twin critic."""
    alpha_lr: float = 3e-4
    """Adam learning rate of the log temperature."""
    gamma: float = 0.98
    """Discount factor; 0.98 spans the ~50-step horizon of a 100-step reaching episode."""
    tau: float = 0.005
    """Polyak rate of the target critic: target <- (1 - tau) target + tau critic, per update."""
    batch_size: int = 256
    """Transitions per update (read by the training loop when sampling)."""
    init_temperature: float = 0.1
    """Initial entropy temperature alpha."""
    target_entropy: float | None = None
    """Entropy the temperature is tuned towards, nats; None means -|A|."""
    log_std_bounds: tuple[float, float] = (-5.0, 2.0)
    """Range of the policy's pre-squash log standard deviation."""
    reward_scale: float = 100.0
    """Factor on rewards in the TD target. The env pays -0.01 per step; scaled to HER's usual -1,
    the entropy bonus at the default temperature does not drown the reward (scaling rewards by c
    is SAC with temperature alpha / c)."""
    normalize_obs: bool = True
    """Normalise inputs with running mean/std, updated from every training batch."""
    obs_clip: float = 5.0
    """Clip normalised inputs to [-obs_clip, obs_clip] standard deviations."""
    seed: int = 0
    """Seed of the network initialisation and of the agent's own sampling noise."""
    device: str = "cpu"
    """Torch device; on "cpu", act() runs the numpy fast path."""

    def __post_init__(self) -> None:
        check_sac_settings(self)
        if not self.obs_keys or not all(isinstance(key, str) for key in self.obs_keys):
            raise ValueError(
                f"agent.obs_keys must name one or more observation keys, got {self.obs_keys!r}"
            )
        target = self.target_entropy
        if target is not None and not (_is_number(target) and math.isfinite(target)):
            raise ValueError(f"agent.target_entropy must be a finite number or None, got {target}")
        if not (_is_number(self.obs_clip) and 0 < self.obs_clip < math.inf):
            raise ValueError(f"agent.obs_clip must be a finite number > 0, got {self.obs_clip}")


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def check_sac_settings(config: Any) -> None:
    """A ValueError naming the field, its value and what is allowed, for the settings SAC
    agents share (`SACConfig`, the stage-2 `ResidualConfig`): learning rates, discount, Polyak
    rate, batch size, temperature, reward scale, log-std range and hidden layer widths."""
    for name in ("actor_lr", "critic_lr"):
        value = getattr(config, name)
        if not (_is_number(value) and 0 < value < math.inf):
            raise ValueError(f"agent.{name} must be a finite number > 0, got {value}")
    if not (_is_number(config.alpha_lr) and 0 <= config.alpha_lr < math.inf):
        raise ValueError(
            f"agent.alpha_lr must be a finite number >= 0 (0: the temperature stays at "
            f"init_temperature), got {config.alpha_lr}"
        )
    if not (_is_number(config.gamma) and 0 <= config.gamma <= 1):
        raise ValueError(f"agent.gamma must be in [0, 1], got {config.gamma}")
    if not (_is_number(config.tau) and 0 < config.tau <= 1):
        raise ValueError(f"agent.tau must be in (0, 1], got {config.tau}")
    batch_size = config.batch_size
    if (
        not isinstance(batch_size, int | np.integer)
        or isinstance(batch_size, bool)
        or batch_size < 1
    ):
        raise ValueError(f"agent.batch_size must be an integer >= 1, got {batch_size!r}")
    for name in ("init_temperature", "reward_scale"):
        value = getattr(config, name)
        if not (_is_number(value) and 0 < value < math.inf):
            raise ValueError(f"agent.{name} must be a finite number > 0, got {value}")
    sizes = config.hidden_sizes
    if not (
        isinstance(sizes, tuple | list)
        and sizes
        and all(
            isinstance(n, int | np.integer) and not isinstance(n, bool) and n >= 1 for n in sizes
        )
    ):
        raise ValueError(
            f"agent.hidden_sizes must be one or more layer widths (integers >= 1), got {sizes!r}"
        )
    bounds = config.log_std_bounds
    if not (
        isinstance(bounds, tuple | list)
        and len(bounds) == 2
        and all(_is_number(b) and math.isfinite(b) for b in bounds)
        and bounds[0] < bounds[1]
    ):
        raise ValueError(
            f"agent.log_std_bounds must be two finite numbers (low, high) with low < high, "
            f"got {bounds!r}"
        )


class NonFiniteLossError(FloatingPointError):
    """A training loss became NaN or infinite; raised before the bad gradient is applied."""


def finite_value(name: str, loss: torch.Tensor, num_updates: int) -> float:
    """`loss.item()`, or NonFiniteLossError naming the loss when it is NaN or infinite."""
    value = loss.item()
    if not math.isfinite(value):
        raise NonFiniteLossError(
            f"{name} is {value} at update {num_updates}; check the batch for NaN/inf "
            "observations or rewards, and the learning rates"
        )
    return value


def flatten_obs(obs: Mapping[str, Any], keys: tuple[str, ...]) -> np.ndarray:
    """Concatenate vector observation entries into features (D,) or (B, D), float32."""
    return np.concatenate([np.asarray(obs[key], dtype=np.float32) for key in keys], axis=-1)


@torch.no_grad()
def soft_update(target: torch.nn.Module, source: torch.nn.Module, tau: float) -> None:
    """Polyak averaging in place: target <- (1 - tau) target + tau source."""
    target_params = list(target.parameters())
    torch._foreach_lerp_(target_params, list(source.parameters()), tau)


class SACAgent:
    """Goal-conditioned SAC agent; a policy in the ``act(obs) -> action`` sense."""

    def __init__(self, config: SACConfig, obs_dim: int, action_dim: int) -> None:
        """Build networks and optimisers.

        Args:
            config: agent settings.
            obs_dim: size D of the flattened ``config.obs_keys`` features.
            action_dim: size A of the action, in [-1, 1]^A.
        """
        self.config = config
        self.obs_dim = obs_dim
        self.action_dim = action_dim
        self.device = torch.device(config.device)
        # Initialise on the CPU under the seed without disturbing the global torch RNG.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            actor = Actor(obs_dim, action_dim, config.hidden_sizes, config.log_std_bounds)
            critic = EnsembleCritic(obs_dim, action_dim, config.hidden_sizes)
        self.actor = actor.to(self.device)
        self.critic = critic.to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.normalizer = RunningNormalizer(obs_dim, config.obs_clip).to(self.device)
        self.log_alpha = torch.tensor(
            math.log(config.init_temperature), device=self.device, requires_grad=True
        )
        self.target_entropy = (
            -float(action_dim) if config.target_entropy is None else config.target_entropy
        )
        # Fused Adam: one kernel per optimiser step instead of a loop over tensors.
        self.actor_optim = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, fused=True)
        self.critic_optim = torch.optim.Adam(
            self.critic.parameters(), lr=config.critic_lr, fused=True
        )
        self.alpha_optim = torch.optim.Adam([self.log_alpha], lr=config.alpha_lr, fused=True)
        self._generator = torch.Generator(self.device).manual_seed(config.seed)
        self._rng = np.random.default_rng(config.seed)
        self.num_updates = 0
        self._fast_actor = self._make_fast_actor()

    @classmethod
    def from_spaces(
        cls, config: SACConfig, observation_space: spaces.Dict, action_space: spaces.Box
    ) -> SACAgent:
        """An agent sized for a Gymnasium Dict observation space and a [-1, 1]^A action space."""
        if not (np.all(action_space.low == -1.0) and np.all(action_space.high == 1.0)):
            raise ValueError("SACAgent expects actions in [-1, 1]; rescale the env's action space")
        obs_dim = sum(math.prod(observation_space[key].shape) for key in config.obs_keys)
        return cls(config, obs_dim, math.prod(action_space.shape))

    def _make_fast_actor(self) -> NumpyActor | None:
        if self.device.type != "cpu":
            return None
        return NumpyActor(self.actor, self.normalizer if self.config.normalize_obs else None)

    @property
    def alpha(self) -> float:
        """Current entropy temperature."""
        return float(self.log_alpha.detach().exp())

    def _normalize(self, features: torch.Tensor) -> torch.Tensor:
        return self.normalizer(features) if self.config.normalize_obs else features

    def act(self, obs: Mapping[str, Any] | np.ndarray, deterministic: bool = False) -> np.ndarray:
        """Action for one observation or a batch.

        On a CPU device this runs :class:`NumpyActor` (about 12 us at batch 1 on a 2-core EPYC
        VM, against about 45 us through torch); otherwise torch in inference mode.

        Args:
            obs: observation dict holding ``config.obs_keys`` with vectors (d,) or (B, d), or
                already flattened features (D,) or (B, D).
            deterministic: return tanh(mean) instead of a sample.

        Returns:
            Action (A,) or (B, A), float32 in [-1, 1].
        """
        if isinstance(obs, Mapping):
            features = flatten_obs(obs, self.config.obs_keys)
        else:
            features = np.asarray(obs, dtype=np.float32)
        if self._fast_actor is not None:
            return self._fast_actor(features, deterministic, self._rng)
        with torch.inference_mode():
            x = self._normalize(torch.as_tensor(features, device=self.device))
            if deterministic:
                return self.actor.mode(x).cpu().numpy()
            return self.actor.sample(x, self._generator)[0].cpu().numpy()

    def update(self, batch: Batch) -> dict[str, float]:
        """One gradient step on critic, actor and temperature, then the target soft update.

        Args:
            batch: transitions from the replay buffer (any batch size).

        Returns:
            Metrics: ``train/critic_loss``, ``train/q_mean``, ``train/target_q_mean``,
            ``train/batch_reward``, ``train/actor_loss``, ``train/entropy`` (nats, estimated as
            -log pi), ``train/alpha``, ``train/alpha_loss``.

        Raises:
            NonFiniteLossError: when a loss is NaN or infinite (no parameter is changed by it).
        """
        obs, action, reward, next_obs, done = self._to_tensors(batch)
        if self.config.normalize_obs:
            self.normalizer.update(obs)
        obs, next_obs = self._normalize(obs), self._normalize(next_obs)
        discount = batch.get("discount")
        if discount is not None:  # n-step returns: gamma ** steps per transition
            discount = torch.as_tensor(discount, dtype=torch.float32, device=self.device)
        metrics = self._update_critic(obs, action, reward, next_obs, done, discount)
        metrics |= self._update_actor_and_temperature(obs)
        soft_update(self.critic_target, self.critic, self.config.tau)
        self.num_updates += 1
        return metrics

    def _to_tensors(self, batch: Batch) -> tuple[torch.Tensor, ...]:
        keys = self.config.obs_keys

        def tensor(array: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(array, dtype=torch.float32, device=self.device)

        return (
            tensor(flatten_obs(batch["obs"], keys)),
            tensor(batch["action"]),
            tensor(batch["reward"]),
            tensor(flatten_obs(batch["next_obs"], keys)),
            tensor(batch["done"]),
        )

    def _update_critic(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        reward: torch.Tensor,
        next_obs: torch.Tensor,
        done: torch.Tensor,
        discount: torch.Tensor | None = None,
    ) -> dict[str, float]:
        cfg = self.config
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            next_action, next_log_prob = self.actor.sample(next_obs, self._generator)
            next_q = self.critic_target(next_obs, next_action).min(0).values
            next_value = next_q - alpha * next_log_prob
            discount = cfg.gamma if discount is None else discount
            target_q = cfg.reward_scale * reward + discount * (1.0 - done) * next_value
        q = self.critic(obs, action)
        # Paper Eq. (critic_loss), summed over the two Q-networks.
        critic_loss = 0.5 * (q - target_q).pow(2).mean(1).sum()
        loss_value = self._check_finite("train/critic_loss", critic_loss)
        self.critic_optim.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_optim.step()
        return {
            "train/critic_loss": loss_value,
            "train/q_mean": q.detach().mean().item(),
            "train/target_q_mean": target_q.mean().item(),
            "train/batch_reward": reward.mean().item(),
        }

    def _update_actor_and_temperature(self, obs: torch.Tensor) -> dict[str, float]:
        alpha = self.log_alpha.detach().exp()
        # The actor loss needs gradients through Q w.r.t. the action only; freezing the critic
        # skips computing its weight gradients.
        self.critic.requires_grad_(False)
        try:
            action, log_prob = self.actor.sample(obs, self._generator)
            q = self.critic(obs, action).min(0).values
            actor_loss = (alpha * log_prob - q).mean()
            actor_value = self._check_finite("train/actor_loss", actor_loss)
            self.actor_optim.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_optim.step()
        finally:
            self.critic.requires_grad_(True)

        log_prob = log_prob.detach()
        alpha_loss = (self.log_alpha.exp() * (-log_prob - self.target_entropy)).mean()
        alpha_value = self._check_finite("train/alpha_loss", alpha_loss)
        self.alpha_optim.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_optim.step()
        return {
            "train/actor_loss": actor_value,
            "train/entropy": -log_prob.mean().item(),
            "train/alpha": alpha.item(),
            "train/alpha_loss": alpha_value,
        }

    def _check_finite(self, name: str, loss: torch.Tensor) -> float:
        return finite_value(name, loss, self.num_updates)

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume: networks, optimisers, temperature, normaliser, RNG states,
        and the config as a plain dict. Only tensors and Python primitives, so
        ``torch.load(path, weights_only=True)`` reads it."""
        return {
            "config": dataclasses.asdict(self.config),
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "normalizer": self.normalizer.state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "actor_optim": self.actor_optim.state_dict(),
            "critic_optim": self.critic_optim.state_dict(),
            "alpha_optim": self.alpha_optim.state_dict(),
            "num_updates": self.num_updates,
            "torch_generator": self._generator.get_state(),
            "numpy_rng": self._rng.bit_generator.state,
        }

    def policy_state_keys(self) -> tuple[str, ...]:
        """Keys of `state_dict()` a policy file keeps: acting needs the actor and normaliser,
        stage 2 the critic as the frozen base Q-function."""
        return ("config", "actor", "critic", "normalizer", "log_alpha")

    def load_policy_state(self, state: Mapping[str, Any]) -> None:
        """Restore the acting part only (actor, critic as its own target, normaliser,
        temperature), as kept by a policy file; optimisers and RNG states keep their values."""
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic"])
        self.normalizer.load_state_dict(state["normalizer"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self._fast_actor = self._make_fast_actor()

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from :meth:`state_dict` (values are copied into the existing tensors)."""
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.normalizer.load_state_dict(state["normalizer"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.actor_optim.load_state_dict(state["actor_optim"])
        self.critic_optim.load_state_dict(state["critic_optim"])
        self.alpha_optim.load_state_dict(state["alpha_optim"])
        self.num_updates = int(state["num_updates"])
        self._generator.set_state(state["torch_generator"])
        self._rng.bit_generator.state = state["numpy_rng"]
        self._fast_actor = self._make_fast_actor()
