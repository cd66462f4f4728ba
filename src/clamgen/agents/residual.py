"""Stage 2 of CLAMGen: a vision residual on top of the frozen joint-space base policy.

Paper, "Obstacle-Avoidance via a Learned Residual" and "Learned 3D fusion":
- Q(s, a) = Q_base(joints, goal, a) + Q_res(images, joints, goal, a); Q_base is the stage-1
  critic, frozen unless `finetune_base`; Q_res's output layer starts at zero, so Q starts
  exactly at Q_base. Clipped double-Q on the sum.
- The action is the base action plus a residual, added before the tanh squashing:
  a = tanh(mu_base(s1) + mu_res(s) + sigma_res(s) eps). Added there, the sum stays in [-1, 1]
  and the log-probability stays exact; with mu_res's output layer at zero the policy's mean
  action starts exactly at the base action.
- Warm-up: for the first `warmup_updates` the actor maximises Q_base - alpha log pi (cloning the
  base), while Q_res already learns from the critic loss.
- The multi-view encoder is trained by the critic loss and the auxiliary losses (CURL with the
  across-view term, collision prediction); the actor reads its features detached (as in CURL and
  SAC-AE). View dropout masks whole views of the training batch.
- `obs_source="obstacles"` replaces the images by the obstacles' true poses (a privileged upper
  bound that trains fast); `residual=False` is the "no residual" ablation (plain SAC on the same
  inputs, no base policy or base Q).
- Image-only policy (`use_low_dim=False`, the paper's Table 1 image rows): the networks see the
  images alone. For training only, `privileged_critic` also gives the critic joints and goal
  (asymmetric actor-critic) and `privileged_base_q` adds the frozen Q_base to it, so the actor
  learns from a critic that already knows the task.

`update()` reads as the recipe: augment, critic (+ encoder), auxiliary losses, actor and
temperature, target updates.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from clamgen.agents.augment import center_crop, random_crop
from clamgen.agents.aux_losses import (
    AuxLossConfig,
    CollisionHead,
    CURLHead,
    collision_loss,
    make_momentum_copy,
    momentum_update,
)
from clamgen.agents.encoders import (
    EncoderConfig,
    LowDimEncoder,
    MultiViewEncoder,
    view_dropout_mask,
)
from clamgen.agents.networks import Actor, EnsembleCritic, RunningNormalizer, mlp
from clamgen.agents.sac import NonFiniteLossError, SACAgent, flatten_obs, soft_update
from clamgen.replay.episode import Batch

LOW_DIM_KEYS = ("observation", "desired_goal")


@dataclass(frozen=True)
class ResidualConfig:
    """Stage-2 agent settings (every component switchable for the ablations)."""

    obs_source: Literal["images", "obstacles"] = "images"
    """"images" (camera views) or "obstacles" (the obstacles' true poses, privileged)."""
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    """Multi-view encoder; `encoder.image_size` is the crop the networks see."""
    aux: AuxLossConfig = field(default_factory=AuxLossConfig)
    """Auxiliary losses (weights 0 switch them off)."""
    crop_padding: int = 4
    """Stored images are `encoder.image_size + 2 * crop_padding` pixels; training crops them at
    random offsets (CURL's augmentation), acting takes the centre crop."""
    residual: bool = True
    """Learn a residual on the frozen base (CLAMGen); False: the "no residual" ablation."""
    use_low_dim: bool = True
    """Feed joints and goal to the networks. False: the image-only policy of the paper's
    Table 1 (the goal is inferred from the images; needs `residual=False`)."""
    privileged_critic: bool = False
    """Image-only policy (`use_low_dim=False`) with a critic that also sees joints and goal
    (an asymmetric actor-critic): the critic is used in training only, so the policy still acts
    from images alone. False: the critic sees what the policy sees."""
    privileged_base_q: bool = False
    """With `privileged_critic`: the critic is Q_base(joints, goal, a) + Q_res(images, joints,
    goal, a) as in CLAMGen's residual, Q_res starting at zero, and the actor warms up on Q_base.
    The stage-1 critic thus tells the image-only actor from its first update which actions reach
    the goal; the policy still has no base action and acts from images alone."""
    encoder_from_critic: bool = True
    """The critic loss trains the encoder (CURL, SAC-AE, the paper). False: the critic reads the
    visual encoding detached, so only the contrastive and state-regression losses train the
    encoder; meant for a privileged critic, which sees the full state and whose gradients
    would otherwise drown the state-regression signal that locates the target."""
    finetune_base: bool = False
    """Also update the base actor and base critic (the paper says it can)."""
    warmup_updates: int = 1_000
    """Updates during which the actor maximises Q_base only (clones the base policy)."""
    view_dropout: float = 0.25
    """Probability of dropping each view of a training sample (never all of them); 0: off."""
    hidden_sizes: tuple[int, ...] = (256, 256)
    """The controller's dense layers (actor and each Q), ReLU."""
    obstacle_feature_dim: int = 50
    """Size of the obstacle-pose encoding when `obs_source` is "obstacles"."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the critic, the encoder and the auxiliary heads."""
    alpha_lr: float = 3e-4
    """Adam learning rate of the log temperature."""
    gamma: float = 0.98
    """Discount factor (as stage 1)."""
    tau: float = 0.01
    """Polyak rate of the target critic (encoder included)."""
    batch_size: int = 128
    """Transitions per update."""
    init_temperature: float = 0.01
    """Initial entropy temperature: small, so exploration starts near the base policy."""
    reward_scale: float = 100.0
    """Factor on rewards (as stage 1: -0.01 per step becomes -1)."""
    log_std_bounds: tuple[float, float] = (-5.0, 2.0)
    """Range of the residual's pre-squash log standard deviation."""
    seed: int = 0
    """Seed of the initialisation and of the agent's own sampling."""
    device: str = "cpu"
    """Torch device."""

    def __post_init__(self) -> None:
        if self.obs_source not in ("images", "obstacles"):
            raise ValueError(f"obs_source must be 'images' or 'obstacles', got {self.obs_source!r}")
        if not 0.0 <= self.view_dropout < 1.0:
            raise ValueError(f"view_dropout must be in [0, 1), got {self.view_dropout}")
        if self.crop_padding < 0:
            raise ValueError("crop_padding must be >= 0")
        if not self.use_low_dim and (self.residual or self.obs_source != "images"):
            raise ValueError("use_low_dim=False (image-only) needs residual=False and images")
        if self.privileged_critic and self.use_low_dim:
            raise ValueError("privileged_critic is for image-only agents (use_low_dim=False)")
        if self.privileged_base_q and not self.privileged_critic:
            raise ValueError("privileged_base_q needs privileged_critic (Q_base reads the state)")
        aux = self.aux
        if not self.encoder_from_critic and (
            self.obs_source != "images"
            or aux.curl_weight == aux.across_view_weight == aux.state_weight == 0
        ):
            raise ValueError(
                "encoder_from_critic=False needs images and a contrastive or state-regression "
                "loss (aux weights > 0) to train the encoder"
            )

    @property
    def uses_base_q(self) -> bool:
        """Whether the critic is Q_base + Q_res (the residual, or a privileged base Q)."""
        return self.residual or self.privileged_base_q

    @property
    def stored_image_size(self) -> int:
        """Side of the images the environment renders and the replay stores."""
        return self.encoder.image_size + 2 * self.crop_padding


class ObstacleEncoder(nn.Module):
    """Obstacles' true poses (B, N, 8) -> encoding (B, D): the privileged stand-in for images."""

    def __init__(self, num_obstacles: int, feature_dim: int) -> None:
        super().__init__()
        self.net = mlp(num_obstacles * 8, (128,), feature_dim)
        self.norm = nn.LayerNorm(feature_dim)

    def forward(self, obstacles: torch.Tensor, view_mask: torch.Tensor | None = None):
        del view_mask
        return torch.tanh(self.norm(self.net(obstacles.flatten(1))))


class ResidualCritic(nn.Module):
    """Encoder + low-dim encoder + twin Q controller: Q_res(s, a), (2, B)."""

    def __init__(
        self,
        encoder: nn.Module,
        feature_dim: int,
        low_dim: int,
        low_dim_size: int,
        action_dim: int,
        hidden_sizes: tuple[int, ...],
        zero_output: bool,
    ) -> None:
        super().__init__()
        self.encoder = encoder
        self.low_dim = LowDimEncoder(low_dim, low_dim_size)
        self.q = EnsembleCritic(feature_dim + low_dim_size, action_dim, hidden_sizes)
        if zero_output:  # Q_res starts at exactly 0, so Q starts at Q_base
            nn.init.zeros_(self.q.layers[-1].weight)
            nn.init.zeros_(self.q.layers[-1].bias)

    def features(self, visual_in: torch.Tensor, low_dim_in: torch.Tensor, view_mask=None):
        """(latent, visual encoding): the fused latent (B, Dv + Dl) and the visual part."""
        return self.fuse(self.encoder(visual_in, view_mask), low_dim_in)

    def fuse(self, visual: torch.Tensor, low_dim_in: torch.Tensor):
        """(latent, visual) from an already computed visual encoding."""
        return torch.cat([visual, self.low_dim(low_dim_in)], dim=-1), visual

    def forward(self, latent: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.q(latent, action)


class ResidualActor(nn.Module):
    """Low-dim encoder + controller on the (detached) visual encoding: residual mean, log std."""

    def __init__(
        self,
        feature_dim: int,
        low_dim: int,
        low_dim_size: int,
        action_dim: int,
        hidden_sizes: tuple[int, ...],
        log_std_bounds,
        zero_mean: bool,
    ) -> None:
        super().__init__()
        self.low_dim = LowDimEncoder(low_dim, low_dim_size)
        self.policy = Actor(feature_dim + low_dim_size, action_dim, hidden_sizes, log_std_bounds)
        if zero_mean:
            last = self.policy.trunk[-1]
            with torch.no_grad():
                last.weight[:action_dim].zero_()
                last.bias[:action_dim].zero_()

    def forward(self, visual: torch.Tensor, low_dim_in: torch.Tensor):
        return self.policy(torch.cat([visual, self.low_dim(low_dim_in)], dim=-1))


@dataclass
class _TrainInputs:
    """One training batch as tensors (B = batch size, A = action size)."""

    low_dim: torch.Tensor  # (B, 9) normalised joints + goal, as the critic sees them
    next_low_dim: torch.Tensor
    actor_low_dim: torch.Tensor  # as the actor sees them (zeros for an image-only policy)
    next_actor_low_dim: torch.Tensor
    state: torch.Tensor  # (B, 9) the true normalised joints + goal (the state head's target)
    visual_in: torch.Tensor  # (B, V, 4, crop, crop) uint8, or (B, N, 8) obstacle poses
    next_visual_in: torch.Tensor
    key_in: torch.Tensor | None  # another crop of visual_in's images (CURL's key)
    action: torch.Tensor  # (B, A)
    reward: torch.Tensor  # (B,)
    done: torch.Tensor  # (B,)
    collided: torch.Tensor  # (B,)
    view_mask: torch.Tensor | None  # (B, V) bool
    view_features: torch.Tensor | None = None  # (B, V, F) conv features of visual_in


class ResidualAgent:
    """CLAMGen's stage-2 agent; a policy in the `act(obs) -> action` sense."""

    def __init__(self, config: ResidualConfig, base: SACAgent, num_obstacles: int = 2) -> None:
        self.config = config
        self.device = torch.device(config.device)
        self.base = base
        action_dim = base.action_dim
        self.action_dim = action_dim
        low_dim = base.obs_dim
        enc = config.encoder
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            if config.obs_source == "images":
                encoder: nn.Module = MultiViewEncoder(enc)
                feature_dim = enc.feature_dim
            else:
                encoder = ObstacleEncoder(num_obstacles, config.obstacle_feature_dim)
                feature_dim = config.obstacle_feature_dim
            self.critic = ResidualCritic(
                encoder,
                feature_dim,
                low_dim,
                enc.low_dim_size,
                action_dim,
                config.hidden_sizes,
                config.uses_base_q,
            )
            self.actor = ResidualActor(
                feature_dim,
                low_dim,
                enc.low_dim_size,
                action_dim,
                config.hidden_sizes,
                config.log_std_bounds,
                config.residual,
            )
            latent_dim = feature_dim + enc.low_dim_size
            self.collision_head = CollisionHead(
                latent_dim, action_dim, config.aux.collision_hidden_sizes
            )
            self.curl = CURLHead(feature_dim, across_view=config.aux.across_view_weight > 0)
            self.state_head = mlp(feature_dim, (256,), low_dim)
        self.feature_dim = feature_dim
        self.critic.to(self.device)
        self.actor.to(self.device)
        self.collision_head.to(self.device)
        self.curl.to(self.device)
        self.state_head.to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.key_encoder = make_momentum_copy(self.critic.encoder)
        # The base: its normaliser scales the low-dim input of every network (frozen statistics).
        self.base_actor = base.actor
        self.base_critic = base.critic
        self.base_critic_target = copy.deepcopy(base.critic).requires_grad_(False)
        self.normalizer: RunningNormalizer = base.normalizer
        for module in (self.base_actor, self.base_critic):
            module.requires_grad_(config.finetune_base)
        self.log_alpha = torch.tensor(
            math.log(config.init_temperature), device=self.device, requires_grad=True
        )
        self.target_entropy = -float(action_dim)
        critic_params = [
            *self.critic.parameters(),
            *self.collision_head.parameters(),
            *self.curl.parameters(),
            *self.state_head.parameters(),
        ]
        actor_params = list(self.actor.parameters())
        if config.finetune_base:
            critic_params += list(self.base_critic.parameters())
            actor_params += list(self.base_actor.parameters())
        self.critic_optim = torch.optim.Adam(critic_params, lr=config.critic_lr)
        self.actor_optim = torch.optim.Adam(actor_params, lr=config.actor_lr)
        self.alpha_optim = torch.optim.Adam([self.log_alpha], lr=config.alpha_lr)
        self._generator = torch.Generator(self.device).manual_seed(config.seed)
        self.num_updates = 0

    # ------------------------------------------------------------------ inputs
    def _visual_key(self) -> str:
        return "images" if self.config.obs_source == "images" else "obstacles"

    def _state(self, obs: Mapping[str, Any]) -> torch.Tensor:
        """The true normalised joints + goal (B, 9)."""
        return self.normalizer(torch.as_tensor(flatten_obs(obs, LOW_DIM_KEYS), device=self.device))

    def _seen(self, state: torch.Tensor, critic: bool = False) -> torch.Tensor:
        """`state` as the actor (or the critic) sees it: zeros for an image-only agent, whose
        networks then see nothing but the images (the env still records joints and goals for
        relabelling), unless its critic is privileged."""
        if self.config.use_low_dim or (critic and self.config.privileged_critic):
            return state
        return torch.zeros_like(state)

    def _visual(self, obs: Mapping[str, Any], train: bool) -> torch.Tensor:
        """Images cropped to the encoder's size (random offsets when training), or poses."""
        value = torch.as_tensor(np.asarray(obs[self._visual_key()]), device=self.device)
        if self.config.obs_source != "images":
            return value.float()
        crop = self.config.encoder.image_size
        if train:
            return random_crop(value, crop, self._generator)
        return center_crop(value, crop)

    def _view_mask(self, batch_size: int) -> torch.Tensor | None:
        p = self.config.view_dropout
        if p == 0 or self.config.obs_source != "images":
            return None
        return view_dropout_mask(batch_size, self.config.encoder.num_views, p, self._generator)

    def _pre_squash(self, visual: torch.Tensor, low_dim: torch.Tensor):
        """Mean and log std of the combined policy before the tanh."""
        mean, log_std = self.actor(visual, low_dim)
        if self.config.residual:
            base_mean, _ = self.base_actor(low_dim)
            mean = mean + base_mean
        return mean, log_std

    def _sample(self, visual, low_dim):
        mean, log_std = self._pre_squash(visual, low_dim)
        noise = torch.randn(mean.shape, generator=self._generator, device=mean.device)
        pre = mean + log_std.exp() * noise
        gaussian = -0.5 * noise.pow(2) - log_std - 0.5 * math.log(2 * math.pi)
        squash = 2.0 * (math.log(2.0) - pre - F.softplus(-2.0 * pre))
        return torch.tanh(pre), (gaussian - squash).sum(-1)

    def _q(self, critic: ResidualCritic, base_critic, latent, low_dim, action) -> torch.Tensor:
        q = critic(latent, action)
        if self.config.uses_base_q:
            q = q + base_critic(low_dim, action)
        return q

    # ---------------------------------------------------------------- pretrain
    def pretrain_encoder(
        self,
        obs: Mapping[str, Any],
        steps: int,
        batch_size: int,
        lr: float,
        on_step: Callable[[float], None] | None = None,
    ) -> float:
        """Supervised state regression before RL: the encoder and the state head learn to read
        the joints and the goal from the images of `obs` (a batch of N observations with
        `images` and the low-dim keys), on random crops as in training. The target and momentum
        encoders are then set to the result. Returns the last step's loss (normalised MSE).

        Uses the true state, like the state-regression loss; the policy still acts from images.
        """
        if self.config.obs_source != "images":
            raise ValueError("pretrain_encoder needs image observations")
        if steps < 1 or batch_size < 1 or not lr > 0:
            raise ValueError(f"need steps, batch_size >= 1 and lr > 0, got {steps, batch_size, lr}")
        images = torch.as_tensor(np.asarray(obs["images"]), device=self.device)
        states = self._state(obs)
        encoder = self.critic.encoder
        optimizer = torch.optim.Adam([*encoder.parameters(), *self.state_head.parameters()], lr=lr)
        crop = self.config.encoder.image_size
        for _ in range(steps):
            index = torch.randint(
                len(images), (batch_size,), generator=self._generator, device=self.device
            )
            crops = random_crop(images[index], crop, self._generator)
            loss = self._state_loss(encoder(crops), states[index])
            value = _finite("pretrain/state_loss", loss)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            if on_step is not None:
                on_step(value)
        self.critic_target.encoder.load_state_dict(encoder.state_dict())
        self.key_encoder.load_state_dict(encoder.state_dict())
        return value

    def _state_loss(self, visual: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """The state head's regression loss: MSE to the normalised joints + goal."""
        return F.mse_loss(self.state_head(visual), state)

    @torch.inference_mode()
    def predict_state(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The state head's joints and goal (B, 9), unnormalised, from the centre crops."""
        visual = self.critic.encoder(self._visual(obs, train=False))
        state = self.state_head(visual) * self.normalizer.std + self.normalizer.mean32
        return state.cpu().numpy()

    # --------------------------------------------------------------------- act
    @torch.inference_mode()
    def act(self, obs: Mapping[str, Any], deterministic: bool = False) -> np.ndarray:
        """Action (A,) or (B, A) for one observation or a batch (dict with the low-dim keys and
        `images` (or `obstacles`))."""
        single = np.asarray(obs["desired_goal"]).ndim == 1
        if single:
            obs = {k: np.asarray(v)[None] for k, v in obs.items()}
        low_dim = self._seen(self._state(obs))
        visual = self.critic.encoder(self._visual(obs, train=False))
        if deterministic:
            action = torch.tanh(self._pre_squash(visual, low_dim)[0])
        else:
            action = self._sample(visual, low_dim)[0]
        action = action.cpu().numpy()
        return action[0] if single else action

    # ------------------------------------------------------------------ update
    def update(self, batch: Batch) -> dict[str, float]:
        """One step of: critic (+ encoder), auxiliary losses, actor and temperature, targets."""
        cfg = self.config
        x = self._train_inputs(batch)
        # The convs run once on the query crop: the critic (with view dropout) and the
        # contrastive terms (all views) merge the same per-view features.
        if cfg.obs_source == "images":
            x.view_features = self.critic.encoder.conv_trunk(x.visual_in)
            visual = self.critic.encoder.merge(x.view_features, x.view_mask)
        else:
            visual = self.critic.encoder(x.visual_in)
        critic_visual = visual if cfg.encoder_from_critic else visual.detach()
        latent, _ = self.critic.fuse(critic_visual, x.low_dim)
        metrics = self._critic_and_aux_step(latent, visual, x)
        metrics |= self._actor_and_temperature_step(visual.detach(), latent.detach(), x)
        soft_update(self.critic_target, self.critic, cfg.tau)
        momentum_update(self.key_encoder, self.critic.encoder, cfg.aux.encoder_momentum_tau)
        if cfg.finetune_base:
            soft_update(self.base_critic_target, self.base_critic, cfg.tau)
        self.num_updates += 1
        return metrics

    def _train_inputs(self, batch: Batch) -> _TrainInputs:
        """Tensors of a batch: normalised low-dim inputs, random crops, view-dropout mask."""
        device = self.device
        images = self.config.obs_source == "images"
        state, next_state = self._state(batch["obs"]), self._state(batch["next_obs"])
        return _TrainInputs(
            low_dim=self._seen(state, critic=True),
            next_low_dim=self._seen(next_state, critic=True),
            actor_low_dim=self._seen(state),
            next_actor_low_dim=self._seen(next_state),
            state=state,
            visual_in=self._visual(batch["obs"], train=True),
            next_visual_in=self._visual(batch["next_obs"], train=True),
            # A second, independent random crop of the same images: CURL's positive key.
            key_in=self._visual(batch["obs"], train=True) if images else None,
            action=torch.as_tensor(batch["action"], device=device),
            reward=torch.as_tensor(batch["reward"], device=device),
            done=torch.as_tensor(batch["done"], device=device),
            collided=torch.as_tensor(batch["collision"], device=device),
            view_mask=self._view_mask(len(batch["action"])),
        )

    def _critic_and_aux_step(self, latent, visual, x: _TrainInputs) -> dict[str, float]:
        cfg = self.config
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            next_visual = self.critic.encoder(x.next_visual_in, x.view_mask)
            next_action, next_log_prob = self._sample(next_visual, x.next_actor_low_dim)
            next_latent, _ = self.critic_target.features(
                x.next_visual_in, x.next_low_dim, x.view_mask
            )
            next_q = (
                self._q(
                    self.critic_target,
                    self.base_critic_target,
                    next_latent,
                    x.next_low_dim,
                    next_action,
                )
                .min(0)
                .values
            )
            target = cfg.reward_scale * x.reward + cfg.gamma * (1 - x.done) * (
                next_q - alpha * next_log_prob
            )
        q = self._q(self.critic, self.base_critic, latent, x.low_dim, x.action)
        critic_loss = 0.5 * (q - target).pow(2).mean(1).sum()
        metrics = {
            "train/critic_loss": _finite("train/critic_loss", critic_loss),
            "train/q_mean": q.detach().mean().item(),
        }
        loss = critic_loss
        aux = cfg.aux
        if aux.collision_weight > 0:
            logits = self.collision_head(latent, x.action)
            c_loss = collision_loss(logits, x.collided, aux.collision_pos_weight)
            loss = loss + aux.collision_weight * c_loss
            metrics["train/collision_loss"] = _finite("train/collision_loss", c_loss)
            predicted = (logits.detach() > 0).float()
            metrics["train/collision_accuracy"] = (predicted == x.collided).float().mean().item()
        if aux.state_weight > 0:
            state_loss = self._state_loss(visual, x.state)
            loss = loss + aux.state_weight * state_loss
            metrics["train/state_loss"] = _finite("train/state_loss", state_loss)
        if cfg.obs_source == "images" and (aux.curl_weight > 0 or aux.across_view_weight > 0):
            loss = loss + self._contrastive(x.view_features, x.key_in, metrics)
        self.critic_optim.zero_grad(set_to_none=True)
        loss.backward()
        self.critic_optim.step()
        return metrics

    def _contrastive(self, query_views, key_in, metrics: dict[str, float]) -> torch.Tensor:
        """CURL: the query is one random crop through the online encoder (its per-view conv
        features `query_views`), the positive key another random crop of the same images
        through the momentum encoder."""
        aux = self.config.aux
        encoder = self.critic.encoder
        with torch.no_grad():
            key_views = self.key_encoder.conv_trunk(key_in)
            key_z = self.key_encoder.merge(key_views)
        query_z = encoder.merge(query_views)
        loss = torch.zeros((), device=self.device)
        if aux.curl_weight > 0:
            curl = self.curl.instance_loss(query_z, key_z)
            metrics["train/curl_loss"] = _finite("train/curl_loss", curl)
            loss = loss + aux.curl_weight * curl
        if aux.across_view_weight > 0 and self.config.encoder.num_views > 1:
            with torch.no_grad():
                key_single = self.key_encoder.single_view_encodings(key_views)
            across = self.curl.across_view_loss(
                encoder.single_view_encodings(query_views), key_single
            )
            metrics["train/across_view_loss"] = _finite("train/across_view_loss", across)
            loss = loss + aux.across_view_weight * across
        return loss

    def _actor_and_temperature_step(self, visual, latent, x: _TrainInputs) -> dict[str, float]:
        cfg = self.config
        alpha = self.log_alpha.detach().exp()
        warming_up = cfg.uses_base_q and self.num_updates < cfg.warmup_updates
        for module in (self.critic, self.base_critic):
            module.requires_grad_(False)
        try:
            action, log_prob = self._sample(visual, x.actor_low_dim)
            if warming_up:
                # Paper: during warm-up, maximise Q_base - alpha log pi to clone the base policy.
                q = self.base_critic(x.low_dim, action).min(0).values
            else:
                q = self._q(self.critic, self.base_critic, latent, x.low_dim, action)
                q = q.min(0).values
            actor_loss = (alpha * log_prob - q).mean()
            actor_value = _finite("train/actor_loss", actor_loss)
            self.actor_optim.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_optim.step()
        finally:
            self.critic.requires_grad_(True)
            self.base_critic.requires_grad_(cfg.finetune_base)
        alpha_loss = (self.log_alpha.exp() * (-log_prob.detach() - self.target_entropy)).mean()
        self.alpha_optim.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_optim.step()
        return {
            "train/actor_loss": actor_value,
            "train/alpha": alpha.item(),
            "train/entropy": -log_prob.detach().mean().item(),
            "train/warmup": float(warming_up),
        }

    # -------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers, temperature, RNG; tensors and primitives only."""
        return {
            "config": _jsonable(dataclasses.asdict(self.config)),
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "key_encoder": self.key_encoder.state_dict(),
            "actor": self.actor.state_dict(),
            "collision_head": self.collision_head.state_dict(),
            "curl": self.curl.state_dict(),
            "state_head": self.state_head.state_dict(),
            "base_actor": self.base_actor.state_dict(),
            "base_critic": self.base_critic.state_dict(),
            "base_critic_target": self.base_critic_target.state_dict(),
            "normalizer": self.normalizer.state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "critic_optim": self.critic_optim.state_dict(),
            "actor_optim": self.actor_optim.state_dict(),
            "alpha_optim": self.alpha_optim.state_dict(),
            "num_updates": self.num_updates,
            "torch_generator": self._generator.get_state(),
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        for name in (
            "critic",
            "critic_target",
            "key_encoder",
            "actor",
            "collision_head",
            "curl",
            "base_actor",
            "base_critic",
            "base_critic_target",
            "normalizer",
        ):
            getattr(self, name).load_state_dict(state[name])
        if "state_head" in state:  # absent from files written before the state head existed
            self.state_head.load_state_dict(state["state_head"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        for name in ("critic_optim", "actor_optim", "alpha_optim"):
            if name in state:
                getattr(self, name).load_state_dict(state[name])
        self.num_updates = int(state["num_updates"])
        if "torch_generator" in state:
            self._generator.set_state(state["torch_generator"])


def _finite(name: str, loss: torch.Tensor) -> float:
    value = loss.item()
    if not math.isfinite(value):
        raise NonFiniteLossError(f"{name} is {value}; check inputs and learning rates")
    return value


def _jsonable(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _jsonable(v) for k, v in data.items()}
    if isinstance(data, tuple | list):
        return [_jsonable(v) for v in data]
    return data
