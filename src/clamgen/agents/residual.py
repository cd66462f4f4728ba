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

The networks live in one container (`ResidualNetworks`), from which the state dict, the
optimiser groups, the device move and the policy file's keys follow. The auxiliary losses are
modules that own their heads (`clamgen.agents.aux_losses.AuxLoss`). The variant is chosen once
at construction, so `update()` reads as the recipe for all of them: augment, encode, critic
(+ encoder, + auxiliary losses), actor and temperature, target updates.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from clamgen.agents.augment import center_crop, edge_pad, random_crop
from clamgen.agents.aux_losses import (
    AuxDims,
    AuxInputs,
    AuxLossConfig,
    build_aux_losses,
    make_momentum_copy,
    momentum_update,
)
from clamgen.agents.encoders import (
    EncoderConfig,
    LowDimEncoder,
    MultiViewEncoder,
    view_dropout_mask,
)
from clamgen.agents.fast_act import ResidualActing
from clamgen.agents.geometry import (
    NUM_ARM_KEYPOINTS,
    NUM_GOAL_OFFSET_FEATURES,
    arm_keypoints,
    goal_offset_features,
)
from clamgen.agents.networks import (
    Actor,
    EnsembleCritic,
    MixtureActor,
    RunningNormalizer,
    mlp,
    tanh_gaussian_sample,
)
from clamgen.agents.sac import (
    SACAgent,
    check_sac_settings,
    finite_value,
    flatten_obs,
    soft_update,
)
from clamgen.replay.episode import Batch
from clamgen.robot.ur5 import NUM_JOINTS

LOW_DIM_KEYS = ("observation", "desired_goal")
# Critic-guided acting (`ResidualAgent.act_by_critic`): candidate actions per step, and the std
# of their perturbation of the policy's mean before the tanh (1: up to a full step either way).
CRITIC_CANDIDATES = 64
CRITIC_CANDIDATE_NOISE = 1.0


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
    train_crops: Literal["random", "center"] = "random"
    """How the policy's updates crop the stored images: "random", each view of each sample at
    its own random offset (CURL's augmentation, the paper); "center", the centre crop that
    acting takes (beyond the paper: no shift between what is learnt and what is acted on, and
    the views' geometry kept consistent with each other and with joints and goal). The
    contrastive losses' query and key crops stay random either way."""
    train_shift_padding: int = 0
    """With random `train_crops`: the stored images are first widened by this many pixels of
    repeated edge on every side (DrQ's random shift), so that a training crop shifts by up to
    `crop_padding + train_shift_padding` pixels either way instead of `crop_padding`. 0: the
    paper's crops. Beyond the paper."""
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
    arm_keypoints: bool = False
    """Beyond the paper, for `obs_source="obstacles"`: the obstacle encoding also reads points
    along the arm from the joint angles and their offsets to the obstacles
    (`clamgen.agents.geometry`), instead of leaving the forward kinematics to be learned.
    False: the poses alone."""
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
    actor_components: int = 1
    """Beyond the paper, for distilled students only (`clamgen distill`): > 1 makes the
    residual actor propose that many candidate actions and choose one (`MixtureActor`): each
    label trains the candidate nearest to it, so that a teacher's multimodal labels (an
    obstacle passed on either side) are not averaged. 1: one Gaussian (the paper; RL trains
    only this)."""
    previous_action: bool = False
    """Beyond the paper: the actor and critic also read the previous step's executed action
    (the env's `previous_action` observation, `env.previous_action`) beside joints and goal, so
    that a policy can keep to the way round an obstacle it has begun, where a teacher's labels
    hold to a plan. The base and the state-regression target read joints and goal only.
    False: the paper."""
    goal_offset: bool = False
    """Beyond the paper: the actor and critic also read the tip's offset to the goal and its
    direction (`geometry.goal_offset_features`, forward kinematics of the joints: nothing the
    observation lacks), so that the last centimetres to the goal are not a small difference
    of large inputs. The base and the state-regression target read joints and goal only.
    False: the paper (joints and goal)."""
    target_encoder: Literal["target", "online"] = "target"
    """Visual features the target critic reads for s': "target", its own Polyak-averaged copy
    of the encoder (CURL, SAC-AE, the paper); "online", the online encoder's no-grad features,
    as DrQ-v2 does (one conv pass fewer per update)."""
    bc_weight: float = 0.0
    """Beyond the paper: weight of a behaviour-cloning term in the actor loss, the squared
    distance between the policy's mean action and the action of the replay's demonstration
    transitions (a teacher's episodes, `loop.teacher_fraction`), as in Nair et al. 2018. The
    critic's Q values are ~100x the reward (`reward_scale`), so weights of 1-100 matter.
    0: no such term (the paper)."""
    freeze_encoder: bool = False
    """Beyond the paper, for RL fine-tuning of a policy started from a file
    (`Stage2Config.init_policy`, e.g. a distilled student): the visual encoder gets no
    gradient, so RL adjusts the controller on the features the starting policy learnt (and an
    update skips the convs' backward pass). False: trained end to end (the paper)."""
    critic_first_updates: int = 0
    """Beyond the paper, for fine-tuning: the first updates train the critic only (the actor
    and the temperature wait), so that a started policy meets a critic of its own behaviour
    before its first actor step; a fresh Q_res is 0 and its gradient alone would pull the
    actor towards the base. 0: none (the paper)."""
    anchor_weight: float = 0.0
    """Beyond the paper, for fine-tuning: weight of the squared distance (summed over joints)
    between the actor's pre-squash mean and the starting policy's (`start_from` keeps a frozen
    copy of its actor) in the actor loss, so that RL keeps what the starting policy learnt
    where the critic has nothing better. Q values are ~100x the reward (`reward_scale`), so
    weights of 1-100 matter. 0: none."""
    seed: int = 0
    """Seed of the initialisation and of the agent's own sampling."""
    device: str = "cpu"
    """Torch device of every network, the frozen base and its normaliser included."""

    def __post_init__(self) -> None:
        check_sac_settings(self)
        if not (isinstance(self.bc_weight, int | float) and 0 <= self.bc_weight < np.inf):
            raise ValueError(f"agent.bc_weight must be a finite number >= 0, got {self.bc_weight}")
        if not (isinstance(self.anchor_weight, int | float) and 0 <= self.anchor_weight < np.inf):
            raise ValueError(
                f"agent.anchor_weight must be a finite number >= 0, got {self.anchor_weight}"
            )
        for name, low in (
            ("crop_padding", 0),
            ("warmup_updates", 0),
            ("critic_first_updates", 0),
            ("obstacle_feature_dim", 1),
            ("train_shift_padding", 0),
        ):
            value = getattr(self, name)
            if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < low:
                raise ValueError(f"agent.{name} must be an integer >= {low}, got {value!r}")
        if self.train_shift_padding and self.train_crops != "random":
            raise ValueError("agent.train_shift_padding widens random crops: train_crops='random'")
        if self.train_crops not in ("random", "center"):
            raise ValueError(
                f"agent.train_crops must be 'random' or 'center', got {self.train_crops!r}"
            )
        if self.obs_source not in ("images", "obstacles"):
            raise ValueError(f"obs_source must be 'images' or 'obstacles', got {self.obs_source!r}")
        value = self.actor_components
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < 1:
            raise ValueError(f"agent.actor_components must be an integer >= 1, got {value!r}")
        if self.arm_keypoints and self.obs_source != "obstacles":
            raise ValueError("agent.arm_keypoints needs agent.obs_source='obstacles'")
        if self.goal_offset and not self.use_low_dim:
            raise ValueError("agent.goal_offset reads joints and goal: it needs use_low_dim")
        if not 0.0 <= self.view_dropout < 1.0:  # NaN fails too
            raise ValueError(f"agent.view_dropout must be in [0, 1), got {self.view_dropout}")
        if self.target_encoder not in ("target", "online"):
            raise ValueError(
                f"target_encoder must be 'target' or 'online', got {self.target_encoder!r}"
            )
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
    """Obstacles' true poses (B, N, 8) -> encoding (B, D): the privileged stand-in for images.

    With `arm_keypoints` the input is (B, N * 8 + 6), the poses flattened and then the joint
    angles, and the encoding also reads points along the arm (`geometry.arm_keypoints`), each
    point's offset to each obstacle's centre and that distance.
    """

    def __init__(self, num_obstacles: int, feature_dim: int, arm_keypoints: bool = False) -> None:
        super().__init__()
        self.num_obstacles = num_obstacles
        self.arm_keypoints = arm_keypoints
        size = num_obstacles * 8
        if arm_keypoints:
            size += NUM_ARM_KEYPOINTS * (3 + 4 * num_obstacles)
        self.net = mlp(size, (128,), feature_dim)
        self.norm = nn.LayerNorm(feature_dim)

    def forward(self, visual_in: torch.Tensor, view_mask: torch.Tensor | None = None):
        del view_mask
        inputs = visual_in.flatten(1)
        if self.arm_keypoints:
            poses, joints = inputs[:, :-NUM_JOINTS], inputs[:, -NUM_JOINTS:]
            points = arm_keypoints(joints)  # (B, K, 3)
            centres = poses.view(len(poses), self.num_obstacles, 8)[:, :, 2:5]
            offsets = centres[:, :, None] - points[:, None]  # (B, N, K, 3)
            inputs = torch.cat(
                [poses, points.flatten(1), offsets.flatten(1), offsets.norm(dim=-1).flatten(1)], 1
            )
        return torch.tanh(self.norm(self.net(inputs)))


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
        components: int = 1,
    ) -> None:
        super().__init__()
        self.low_dim = LowDimEncoder(low_dim, low_dim_size)
        inputs = feature_dim + low_dim_size
        if components > 1:
            # Randomly initialised means: components that start equal would stay equal.
            self.policy = MixtureActor(inputs, action_dim, hidden_sizes, log_std_bounds, components)
            return
        self.policy = Actor(inputs, action_dim, hidden_sizes, log_std_bounds)
        if zero_mean:
            last = self.policy.trunk[-1]
            with torch.no_grad():
                last.weight[:action_dim].zero_()
                last.bias[:action_dim].zero_()

    def forward(self, visual: torch.Tensor, low_dim_in: torch.Tensor):
        return self.policy(self.features(visual, low_dim_in))

    def features(self, visual: torch.Tensor, low_dim_in: torch.Tensor) -> torch.Tensor:
        return torch.cat([visual, self.low_dim(low_dim_in)], dim=-1)


@dataclass
class _TrainInputs:
    """One training batch as tensors (B = batch size, A = action size)."""

    state: torch.Tensor  # (B, 9) the true normalised joints + goal
    next_state: torch.Tensor
    visual_in: torch.Tensor  # (B, V, 4, crop, crop) uint8 random crops, or (B, N, 8) poses
    next_visual_in: torch.Tensor
    key_in: Callable[[], torch.Tensor]  # draws another crop of visual_in's images (CURL's key)
    action: torch.Tensor  # (B, A)
    reward: torch.Tensor  # (B,)
    done: torch.Tensor  # (B,)
    collided: torch.Tensor  # (B,)
    demonstration: torch.Tensor  # (B,) 1 for a teacher's transitions
    view_mask: torch.Tensor | None  # (B, V) bool, True = view kept
    discount: torch.Tensor | float  # (B,) gamma ** steps of n-step returns, or gamma


class ResidualNetworks(nn.Module):
    """Every network of a stage-2 agent in one container, grouped by what they are for.

    - `policy`: what acting needs, exported in policy files (the critic holds the encoder).
    - `targets`: training-only slow copies (target critic, CURL's momentum key encoder, the
      base's target critic).
    - `aux`: the auxiliary losses and their heads (`clamgen.agents.aux_losses`).
    The state dict, the optimiser groups, the device move and the policy file's keys all
    follow from these groups.
    """

    def __init__(
        self,
        critic: ResidualCritic,
        actor: ResidualActor,
        base: SACAgent,
        aux: nn.ModuleDict,
    ) -> None:
        super().__init__()
        self.policy = nn.ModuleDict(
            {
                "critic": critic,
                "actor": actor,
                "base_actor": base.actor,
                "base_critic": base.critic,
                "normalizer": base.normalizer,
            }
        )
        self.targets = nn.ModuleDict(
            {
                "critic_target": copy.deepcopy(critic).requires_grad_(False),
                "key_encoder": make_momentum_copy(critic.encoder),
                "base_critic_target": copy.deepcopy(base.critic).requires_grad_(False),
            }
        )
        self.aux = aux

    def parts(self) -> dict[str, nn.Module]:
        """Every network by its state-dict key: the policy and target networks by name, the
        auxiliary losses as `aux/<name>`."""
        return {
            **self.policy,
            **self.targets,
            **{f"aux/{name}": loss for name, loss in self.aux.items()},
        }

    def policy_keys(self) -> tuple[str, ...]:
        """State-dict keys a policy file keeps: acting networks and inference-time heads."""
        in_policy = [f"aux/{name}" for name, loss in self.aux.items() if loss.in_policy]
        return (*self.policy, *in_policy)


def imitation_error(
    mean: torch.Tensor,
    target: torch.Tensor,
    pre_squash_weight: float = 1.0,
    action_weight: float = 0.0,
    action_absolute: bool = False,
) -> torch.Tensor:
    """A student's imitation loss on its pre-squash means `mean` against the labels `target`
    (both (B, A), before the tanh): `pre_squash_weight` times their mean squared error plus
    `action_weight` times the mean squared error of their tanh, the actions taken (the mean
    absolute error with `action_absolute`: a median of the labels where they disagree,
    instead of their mean). Before the tanh an error costs the same everywhere; after it,
    what it changes in the action (almost nothing between two saturated values)."""
    loss = pre_squash_weight * torch.mean((mean - target) ** 2)
    if action_weight:
        error = torch.tanh(mean) - torch.tanh(target)
        error = error.abs() if action_absolute else error**2
        loss = loss + action_weight * torch.mean(error)
    return loss


class ResidualAgent:
    """CLAMGen's stage-2 agent; a policy in the `act(obs) -> action` sense.

    The variant (residual or not, images or obstacle poses, image-only with or without a
    privileged critic) is chosen once here, as the functions `_base_mean`, `_base_q`,
    `_critic_view`, `_actor_view` and `_encode`; `update()` is the same recipe for all.
    """

    def __init__(self, config: ResidualConfig, base: SACAgent, num_obstacles: int = 2) -> None:
        self.config = config
        self.device = torch.device(config.device)
        self.base = base
        self.action_dim = action_dim = base.action_dim
        # The networks' low-dim input: normalised joints + goal (the base's), then the previous
        # action and the tip's offset to the goal when the config asks for them.
        low_dim = base.obs_dim + (action_dim if config.previous_action else 0)
        low_dim += NUM_GOAL_OFFSET_FEATURES if config.goal_offset else 0
        enc = config.encoder
        images = config.obs_source == "images"
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            if images:
                encoder: nn.Module = MultiViewEncoder(enc)
                feature_dim = enc.feature_dim
            else:
                encoder = ObstacleEncoder(
                    num_obstacles, config.obstacle_feature_dim, config.arm_keypoints
                )
                feature_dim = config.obstacle_feature_dim
            critic = ResidualCritic(
                encoder,
                feature_dim,
                low_dim,
                enc.low_dim_size,
                action_dim,
                config.hidden_sizes,
                config.uses_base_q,
            )
            actor = ResidualActor(
                feature_dim,
                low_dim,
                enc.low_dim_size,
                action_dim,
                config.hidden_sizes,
                config.log_std_bounds,
                config.residual,
                config.actor_components,
            )
            dims = AuxDims(
                feature_dim=feature_dim,
                latent_dim=feature_dim + enc.low_dim_size,
                action_dim=action_dim,
                state_dim=base.obs_dim,
                num_views=enc.num_views if images else 0,
            )
            aux = build_aux_losses(config.aux, dims)
        self.feature_dim = feature_dim
        self.nets = ResidualNetworks(critic, actor, base, aux).to(self.device)
        if config.freeze_encoder:
            self.critic.encoder.requires_grad_(False)
        self._keep_anchor()
        # The base is frozen unless finetuned; its normaliser scales every network's low-dim
        # input (frozen statistics).
        for module in (self.base_actor, self.base_critic):
            module.requires_grad_(config.finetune_base)
        self.log_alpha = torch.tensor(
            math.log(config.init_temperature), device=self.device, requires_grad=True
        )
        self.target_entropy = -float(action_dim)
        critic_params = [*self.critic.parameters(), *self.nets.aux.parameters()]
        actor_params = list(self.actor.parameters())
        if config.finetune_base:
            critic_params += list(self.base_critic.parameters())
            actor_params += list(self.base_actor.parameters())
        self.critic_optim = _adam(critic_params, config.critic_lr, self.device)
        self.actor_optim = _adam(actor_params, config.actor_lr, self.device)
        self.alpha_optim = _adam([self.log_alpha], config.alpha_lr, self.device)
        self._generator = torch.Generator(self.device).manual_seed(config.seed)
        self.num_updates = 0
        self._choose_variant()
        self.fast_act = ResidualActing.build(self)
        """The deterministic action for one observation in plain calls
        (`clamgen.agents.fast_act`: the same action, faster between renders), or None to act
        through the modules only."""

    def _choose_variant(self) -> None:
        """Pick, once, the pieces in which the variants differ."""
        cfg = self.config
        # The residual adds the base's action before the tanh; otherwise the actor acts alone.
        self._base_mean = (
            (lambda low: self.base_actor(self._true_state(low))[0]) if cfg.residual else _zero
        )
        # Q = Q_base + Q_res (the residual, or a privileged base Q) or Q_res alone.
        self._base_q = self._call_base_q if cfg.uses_base_q else _zero_q
        self._warmup_updates = cfg.warmup_updates if cfg.uses_base_q else 0
        # What the networks see of joints and goal: an image-only policy sees nothing of
        # them (the env still records them for relabelling), unless its critic is privileged.
        blind = torch.zeros_like
        self._actor_view = _identity if cfg.use_low_dim else blind
        self._critic_view = _identity if cfg.use_low_dim or cfg.privileged_critic else blind
        self._critic_features = _identity if cfg.encoder_from_critic else torch.Tensor.detach
        if cfg.obs_source == "images":
            self._encode = self._encode_images
        else:
            self._encode = self._encode_poses
        # The target critic's visual features of s': its own Polyak-averaged encoder (CURL,
        # the paper) or the online encoder's no-grad features (DrQ-v2), one conv pass fewer.
        if cfg.target_encoder == "online":
            self._target_visual = lambda next_visual, x: next_visual
        else:
            self._target_visual = lambda next_visual, x: self.critic_target.encoder(
                x.next_visual_in, x.view_mask
            )

    # ------------------------------------------------------------- the networks
    @property
    def critic(self) -> ResidualCritic:
        return self.nets.policy["critic"]

    @property
    def actor(self) -> ResidualActor:
        return self.nets.policy["actor"]

    @property
    def base_actor(self) -> nn.Module:
        return self.nets.policy["base_actor"]

    @property
    def base_critic(self) -> nn.Module:
        return self.nets.policy["base_critic"]

    @property
    def normalizer(self) -> RunningNormalizer:
        return self.nets.policy["normalizer"]

    @property
    def critic_target(self) -> ResidualCritic:
        return self.nets.targets["critic_target"]

    @property
    def key_encoder(self) -> nn.Module:
        return self.nets.targets["key_encoder"]

    @property
    def base_critic_target(self) -> nn.Module:
        return self.nets.targets["base_critic_target"]

    @property
    def aux_losses(self) -> nn.ModuleDict:
        """The auxiliary losses by name (`clamgen.agents.aux_losses.AUX_LOSSES`)."""
        return self.nets.aux

    @property
    def state_head(self) -> nn.Module:
        """The state-regression head (joints + goal from the visual encoding)."""
        return self.nets.aux["state"].head

    # ------------------------------------------------------------------ inputs
    def low_dim_input(self, obs: Mapping[str, Any]) -> torch.Tensor:
        """The networks' low-dim input: the true normalised joints + goal (B, 9), then the
        previous action (B, 6) when `config.previous_action`, then the tip's offset to the goal
        (B, 6) when `config.goal_offset`."""
        parts = [
            self.normalizer(torch.as_tensor(flatten_obs(obs, LOW_DIM_KEYS), device=self.device))
        ]
        if self.config.previous_action:
            previous = torch.as_tensor(np.asarray(obs["previous_action"]), device=self.device)
            parts.append(previous.float())
        if self.config.goal_offset:
            offset = goal_offset_features(obs["observation"], obs["desired_goal"])
            parts.append(torch.as_tensor(offset, device=self.device))
        return parts[0] if len(parts) == 1 else torch.cat(parts, -1)

    def _true_state(self, low_dim: torch.Tensor) -> torch.Tensor:
        """Normalised joints + goal of a low-dim input: what the base and the state-regression
        target read."""
        return low_dim[..., : self.base.obs_dim]

    def _call_base_q(self, base_critic, low_dim: torch.Tensor, action: torch.Tensor):
        return base_critic(self._true_state(low_dim), action)

    def _visual(
        self, obs: Mapping[str, Any], train: bool, crops: str | None = None
    ) -> torch.Tensor:
        """Images cropped to the encoder's size (when training, as `config.train_crops` or
        `crops` says; acting, the centre crop), or poses."""
        if self.config.obs_source != "images":
            poses = torch.as_tensor(np.asarray(obs["obstacles"]), device=self.device).float()
            if not self.config.arm_keypoints:
                return poses
            joints = torch.as_tensor(np.asarray(obs["observation"]), device=self.device).float()
            return torch.cat([poses.flatten(1), joints], 1)
        value = torch.as_tensor(np.asarray(obs["images"]), device=self.device)
        crop = self.config.encoder.image_size
        if train and (crops or self.config.train_crops) == "random":
            value = edge_pad(value, self.config.train_shift_padding)
            return random_crop(value, crop, self._generator)
        return center_crop(value, crop)

    def _view_mask(self, batch_size: int) -> torch.Tensor | None:
        p = self.config.view_dropout
        if p == 0 or self.config.obs_source != "images":
            return None
        return view_dropout_mask(batch_size, self.config.encoder.num_views, p, self._generator)

    def _train_inputs(self, batch: Batch) -> _TrainInputs:
        """Tensors of a batch: normalised joints + goal, random crops, view-dropout mask."""
        device = self.device

        def tensor(name: str) -> torch.Tensor:
            return torch.as_tensor(batch[name], device=device)

        return _TrainInputs(
            state=self.low_dim_input(batch["obs"]),
            next_state=self.low_dim_input(batch["next_obs"]),
            visual_in=self._visual(batch["obs"], train=True),
            next_visual_in=self._visual(batch["next_obs"], train=True),
            # A second, independent random crop of the same images: CURL's positive key
            # (random whatever `train_crops` says: two centre crops would be the same image).
            key_in=lambda: self._visual(batch["obs"], train=True, crops="random"),
            action=tensor("action"),
            reward=tensor("reward"),
            done=tensor("done"),
            collided=tensor("collision"),
            demonstration=(
                tensor("demonstration")
                if "demonstration" in batch
                else torch.zeros(len(batch["action"]), device=device)
            ),
            view_mask=self._view_mask(len(batch["action"])),
            discount=tensor("discount") if "discount" in batch else self.config.gamma,
        )

    # ------------------------------------------------------------ the pieces
    def _encode_images(self, visual_in, view_mask):
        """(visual encoding (B, Dv), per-view projections (B, V, hidden)) of image crops; the
        convs and each view's projection run once, shared by the critic and the aux losses."""
        encoder = self.critic.encoder
        projections = encoder.project(encoder.conv_trunk(visual_in))
        return encoder.merge_projected(projections, view_mask), projections

    def _encode_poses(self, visual_in, view_mask):
        return self.critic.encoder(visual_in), None

    def _pre_squash(self, visual: torch.Tensor, low_dim: torch.Tensor):
        """Mean and log std of the combined policy before the tanh; `low_dim` as the actor
        sees it."""
        mean, log_std = self.actor(visual, low_dim)
        return mean + self._base_mean(low_dim), log_std

    def _sample(self, visual, low_dim):
        return tanh_gaussian_sample(*self._pre_squash(visual, low_dim), self._generator)

    def _q(self, critic: ResidualCritic, base_critic, latent, low_dim, action) -> torch.Tensor:
        """(2, B) twin Q-values: Q_res on the fused latent, plus Q_base when the variant has
        it; `low_dim` as the critic sees it."""
        return critic(latent, action) + self._base_q(base_critic, low_dim, action)

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
        states = self._true_state(self.low_dim_input(obs))
        encoder, state_loss = self.critic.encoder, self.nets.aux["state"]
        optimizer = torch.optim.Adam([*encoder.parameters(), *state_loss.parameters()], lr=lr)
        crop = self.config.encoder.image_size
        for _ in range(steps):
            index = torch.randint(
                len(images), (batch_size,), generator=self._generator, device=self.device
            )
            crops = random_crop(images[index], crop, self._generator)
            loss = state_loss.regression(encoder(crops), states[index])
            value = finite_value("pretrain/state_loss", loss, self.num_updates)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            if on_step is not None:
                on_step(value)
        self.critic_target.encoder.load_state_dict(encoder.state_dict())
        self.key_encoder.load_state_dict(encoder.state_dict())
        return value

    @torch.inference_mode()
    def predict_state(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The state head's joints and goal (B, 9), unnormalised, from the centre crops."""
        visual = self.critic.encoder(self._visual(obs, train=False))
        state = self.state_head(visual) * self.normalizer.std + self.normalizer.mean32
        return state.cpu().numpy()

    # --------------------------------------------------------------------- act
    def encoder_input(self, obs: Mapping[str, Any]) -> torch.Tensor:
        """What the encoder reads of a batch of observations when acting: the centre crops
        (B, V, 4, S, S) uint8, or the obstacle poses (with the joints, for arm keypoints)."""
        return self._visual(obs, train=False)

    def policy_mean(self, visual: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """The combined policy's mean before the tanh, (B, A): base + residual on the visual
        encoding (B, Dv) and the low-dim input `state` (B, S) (`low_dim_input`; the actor reads
        it as configured, e.g. not at all with `use_low_dim` off)."""
        return self._pre_squash(visual, self._actor_view(state))[0]

    def actor_features(self, visual: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """What the actor's layers read, (B, Dv + L): the visual encoding beside the actor's
        projection of the low-dim input (read as `policy_mean` reads it); heads regressed
        beside a student read it too."""
        return self.actor.features(visual, self._actor_view(state))

    @torch.inference_mode()
    def act(self, obs: Mapping[str, Any], deterministic: bool = False) -> np.ndarray:
        """Action (A,) or (B, A) for one observation or a batch (dict with the low-dim keys and
        `images` (or `obstacles`))."""
        obs, single = _as_batch(obs)
        if deterministic and single and self.fast_act is not None:
            return self.fast_act(obs)[0]
        visual = self.critic.encoder(self.encoder_input(obs))
        state = self.low_dim_input(obs)
        if deterministic:
            action = torch.tanh(self.policy_mean(visual, state))
        else:
            action = self._sample(visual, self._actor_view(state))[0]
        action = action.cpu().numpy()
        return action[0] if single else action

    @torch.inference_mode()
    def act_by_critic(
        self,
        obs: Mapping[str, Any],
        num_candidates: int = CRITIC_CANDIDATES,
        noise: float = CRITIC_CANDIDATE_NOISE,
        generator: torch.Generator | None = None,
    ) -> np.ndarray:
        """Beyond the paper: the best of `num_candidates` actions by the learned Q (the lower
        of the twin Qs, Q_base + Q_res): the policy's mean action and `num_candidates - 1`
        perturbations of it, Gaussian with std `noise` before the tanh. The actor follows Q's
        local gradient, as a potential field does, and can settle where every small step looks
        worse; candidates farther out let the critic pick a way around (QT-Opt acts by
        sampling Q's argmax, Kalashnikov et al. 2018). One observation or a batch, as `act`."""
        obs, single = _as_batch(obs)
        visual = self.critic.encoder(self.encoder_input(obs))
        state = self.low_dim_input(obs)
        mean = self.policy_mean(visual, state)  # (B, A)
        batch, dims = mean.shape
        noise_draw = torch.randn(
            batch, num_candidates - 1, dims, generator=generator, device=self.device
        )
        candidates = torch.tanh(
            torch.cat([mean[:, None], mean[:, None] + noise * noise_draw], dim=1)
        )  # (B, K, A)
        latent, _ = self.critic.fuse(visual, self._critic_view(state))

        def repeat(x: torch.Tensor) -> torch.Tensor:
            return x[:, None].expand(batch, num_candidates, -1).reshape(batch * num_candidates, -1)

        flat = candidates.reshape(batch * num_candidates, dims)
        critic_state = repeat(self._critic_view(state))
        q = self._q(self.critic, self.base_critic, repeat(latent), critic_state, flat)
        best = q.min(dim=0).values.view(batch, num_candidates).argmax(dim=1)
        action = candidates[torch.arange(batch), best].cpu().numpy()
        return action[0] if single else action

    @torch.inference_mode()
    def mean_action(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The combined policy's mean before the tanh, (B, A), for a batch of observations:
        what a distilled student regresses (`imitation_loss`)."""
        visual = self.critic.encoder(self.encoder_input(obs))
        return self.policy_mean(visual, self.low_dim_input(obs)).cpu().numpy()

    def imitation_loss(
        self,
        obs: Mapping[str, Any],
        target_mean: torch.Tensor,
        pre_squash_weight: float = 1.0,
        action_weight: float = 0.0,
        action_absolute: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss, visual encoding): `imitation_error` of this policy's pre-squash mean against
        `target_mean` (B, A), with its weights (with `actor_components` > 1: the candidates'
        winner-takes-all loss, `MixtureActor`, before the tanh only), on random crops with view
        dropout as in training, and the encoding it was computed from; gradients reach the
        encoder and the actor (behaviour cloning of a teacher, `clamgen.experiments.distill`)."""
        visual_in = self._visual(obs, train=True)
        visual = self.critic.encoder(visual_in, self._view_mask(len(target_mean)))
        low_dim = self._actor_view(self.low_dim_input(obs))
        if isinstance(self.actor.policy, MixtureActor):
            if action_weight:
                raise ValueError("a mixture actor's imitation loss is pre-squash only")
            # The candidates regress the label's residual over the base.
            features = self.actor.features(visual, low_dim)
            target = target_mean - self._base_mean(low_dim)
            return self.actor.policy.imitation_loss(features, target), visual
        mean, _ = self._pre_squash(visual, low_dim)
        loss = imitation_error(mean, target_mean, pre_squash_weight, action_weight, action_absolute)
        return loss, visual

    # ------------------------------------------------------------------ update
    def update(self, batch: Batch) -> dict[str, float]:
        """One step of the recipe: encode, critic (+ encoder, + auxiliary losses), actor and
        temperature, target and momentum updates."""
        x = self._train_inputs(batch)
        visual, projections = self._encode(x.visual_in, x.view_mask)
        latent, _ = self.critic.fuse(self._critic_features(visual), self._critic_view(x.state))
        aux = AuxInputs(
            latent=latent,
            visual=visual,
            action=x.action,
            collided=x.collided,
            state=self._true_state(x.state),
            encoder=self.critic.encoder,
            query_projections=projections,
            key_encoder=self.key_encoder,
            key_images=x.key_in,
        )
        metrics = self._update_critic(latent, aux, x)
        metrics |= self._update_actor_and_temperature(visual.detach(), latent.detach(), x)
        self._update_targets()
        self.num_updates += 1
        return metrics

    def _td_target(self, x: _TrainInputs) -> torch.Tensor:
        """r + gamma (1 - done) (min_i Q_target_i(s', a') - alpha log pi(a' | s')), a' ~ pi
        (n-step returns: r summed over the steps and gamma ** steps for gamma)."""
        cfg = self.config
        with torch.no_grad():
            next_visual, _ = self._encode(x.next_visual_in, x.view_mask)
            next_action, next_log_prob = self._sample(next_visual, self._actor_view(x.next_state))
            next_low_dim = self._critic_view(x.next_state)
            next_latent, _ = self.critic_target.fuse(
                self._target_visual(next_visual, x), next_low_dim
            )
            next_q = self._q(
                self.critic_target, self.base_critic_target, next_latent, next_low_dim, next_action
            )
            alpha = self.log_alpha.exp()
            soft_value = next_q.min(0).values - alpha * next_log_prob
            return cfg.reward_scale * x.reward + x.discount * (1 - x.done) * soft_value

    def _update_critic(self, latent, aux: AuxInputs, x: _TrainInputs) -> dict[str, float]:
        """The TD loss plus every weighted auxiliary loss, one optimiser step."""
        target = self._td_target(x)
        q = self._q(self.critic, self.base_critic, latent, self._critic_view(x.state), x.action)
        critic_loss = 0.5 * (q - target).pow(2).mean(1).sum()
        metrics = {
            "train/critic_loss": self._finite("train/critic_loss", critic_loss),
            "train/q_mean": q.detach().mean().item(),
        }
        loss = critic_loss
        for name, aux_loss in self.aux_losses.items():
            if aux_loss.weight == 0:
                continue
            value, extra = aux_loss(aux)
            metrics[f"train/{name}_loss"] = self._finite(f"train/{name}_loss", value)
            metrics |= extra
            loss = loss + aux_loss.weight * value
        self.critic_optim.zero_grad(set_to_none=True)
        loss.backward()
        self.critic_optim.step()
        return metrics

    def _update_actor_and_temperature(self, visual, latent, x: _TrainInputs) -> dict[str, float]:
        """SAC's actor step on detached features (CURL, SAC-AE), then the temperature; none
        while the critic learns first (`critic_first_updates`)."""
        if self.num_updates < self.config.critic_first_updates:
            return {"train/critic_first": 1.0}
        alpha = self.log_alpha.detach().exp()
        warming_up = self.num_updates < self._warmup_updates
        low_dim = self._critic_view(x.state)
        metrics = {}
        with _frozen(self.critic, self.base_critic):
            mean, log_std = self._pre_squash(visual, self._actor_view(x.state))
            action, log_prob = tanh_gaussian_sample(mean, log_std, self._generator)
            if warming_up:
                # Paper: during warm-up, maximise Q_base - alpha log pi to clone the base policy.
                q = self._call_base_q(self.base_critic, low_dim, action)
            else:
                q = self._q(self.critic, self.base_critic, latent, low_dim, action)
            actor_loss = (alpha * log_prob - q.min(0).values).mean()
            actor_value = self._finite("train/actor_loss", actor_loss)
            if self.config.bc_weight > 0:
                bc_loss = _demonstration_mse(torch.tanh(mean), x.action, x.demonstration)
                actor_loss = actor_loss + self.config.bc_weight * bc_loss
                metrics["train/bc_loss"] = bc_loss.item()
                metrics["train/bc_fraction"] = x.demonstration.mean().item()
            if self.config.anchor_weight > 0:
                anchor_loss = self._anchor_loss(mean, visual, self._actor_view(x.state))
                actor_loss = actor_loss + self.config.anchor_weight * anchor_loss
                metrics["train/anchor_loss"] = anchor_loss.item()
            self.actor_optim.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_optim.step()
        alpha_loss = (self.log_alpha.exp() * (-log_prob.detach() - self.target_entropy)).mean()
        self.alpha_optim.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_optim.step()
        return metrics | {
            "train/actor_loss": actor_value,
            "train/alpha": alpha.item(),
            "train/entropy": -log_prob.detach().mean().item(),
            "train/warmup": float(warming_up),
        }

    def _keep_anchor(self) -> None:
        """A frozen copy of the actor as it is now, what `anchor_weight` pulls the actor towards
        (the actor the agent starts with; `start_from` retakes it); none without the term."""
        self._anchor = (
            copy.deepcopy(self.actor).requires_grad_(False)
            if self.config.anchor_weight > 0
            else None
        )

    def _anchor_loss(self, mean: torch.Tensor, visual: torch.Tensor, low_dim: torch.Tensor):
        """Squared distance (summed over joints, averaged over the batch) of the combined
        pre-squash mean to the anchor actor's on the same inputs."""
        with torch.no_grad():
            anchor = self._anchor(visual, low_dim)[0] + self._base_mean(low_dim)
        return (mean - anchor).square().sum(-1).mean()

    def _update_targets(self) -> None:
        cfg = self.config
        soft_update(self.critic_target, self.critic, cfg.tau)
        momentum_update(self.key_encoder, self.critic.encoder, cfg.aux.encoder_momentum_tau)
        if cfg.finetune_base:
            soft_update(self.base_critic_target, self.base_critic, cfg.tau)

    def _finite(self, name: str, loss: torch.Tensor) -> float:
        return finite_value(name, loss, self.num_updates)

    # -------------------------------------------------------------- checkpoints
    def policy_state_keys(self) -> tuple[str, ...]:
        """Keys of `state_dict()` that a policy file keeps (acting needs nothing else)."""
        return ("config", *self.nets.policy_keys(), "log_alpha")

    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers, temperature, RNG; tensors and primitives only."""
        return {
            "config": _jsonable(dataclasses.asdict(self.config)),
            **{key: module.state_dict() for key, module in self.nets.parts().items()},
            "log_alpha": self.log_alpha.detach().clone(),
            "critic_optim": self.critic_optim.state_dict(),
            "actor_optim": self.actor_optim.state_dict(),
            "alpha_optim": self.alpha_optim.state_dict(),
            "num_updates": self.num_updates,
            "torch_generator": self._generator.get_state(),
        }

    def start_from(self, state: Mapping[str, Any]) -> None:
        """Start training from another run's policy (a policy file's agent state, e.g. a
        distilled student's) instead of fresh networks: its acting networks are loaded, the
        target copies (target critic, CURL's key encoder, the base's target critic) restart
        from them, and a frozen copy of its actor becomes the anchor (`anchor_weight` > 0). The
        temperature, optimisers and update count stay fresh. A RuntimeError or KeyError names
        what does not match this agent's config."""
        self._load_parts(state, self.nets.policy, self.nets.policy_keys())
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.key_encoder.load_state_dict(self.critic.encoder.state_dict())
        self.base_critic_target.load_state_dict(self.base_critic.state_dict())
        self._keep_anchor()

    def load_state_dict(self, state: Mapping[str, Any], policy_only: bool = False) -> None:
        """Load `state_dict()`'s output; `policy_only`: a policy file's subset, the training-only
        parts (targets, auxiliary heads, optimisers) keeping their fresh values."""
        parts = self.nets.parts()
        state = self._load_parts(state, self.nets.policy if policy_only else parts, parts)
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        for name in ("critic_optim", "actor_optim", "alpha_optim"):
            if name in state:
                getattr(self, name).load_state_dict(state[name])
        self.num_updates = int(state.get("num_updates", 0))
        if "torch_generator" in state:
            self._generator.set_state(state["torch_generator"])

    def _load_parts(
        self, state: Mapping[str, Any], required: Iterable[str], keys: Iterable[str]
    ) -> Mapping[str, Any]:
        """Load the networks named `keys` that `state` holds (legacy keys translated); a
        KeyError names the `required` ones it lacks. Returns the translated state."""
        state = _translate_legacy_keys(state)
        missing = sorted(set(required) - set(state))
        if missing:
            raise KeyError(f"state has no {missing}")
        parts = self.nets.parts()
        for key in keys:
            if key in state:
                parts[key].load_state_dict(state[key])
        return state


def _adam(params: list, lr: float, device: torch.device) -> torch.optim.Adam:
    """Adam, fused into one kernel per step where torch has one (CPU, CUDA): the same update,
    measured 6x faster than the per-parameter loop for the critic's parameters here."""
    return torch.optim.Adam(params, lr=lr, fused=device.type in ("cpu", "cuda"))


def _demonstration_mse(mean_action, action, demonstration) -> torch.Tensor:
    """Squared distance (summed over joints) of the policy's mean action to the recorded
    action, averaged over the demonstration transitions (0 when the batch has none)."""
    squared = (mean_action - action).square().sum(-1)
    return (squared * demonstration).sum() / demonstration.sum().clamp(min=1.0)


def _as_batch(obs: Mapping[str, Any]) -> tuple[Mapping[str, Any], bool]:
    """(a batch of observations, whether `obs` was a single one, now a batch of 1)."""
    single = np.asarray(obs["desired_goal"]).ndim == 1
    if single:
        obs = {k: np.asarray(v)[None] for k, v in obs.items()}
    return obs, single


def _identity(x):
    return x


def _zero(low_dim: torch.Tensor) -> float:
    return 0.0


def _zero_q(base_critic, low_dim: torch.Tensor, action: torch.Tensor) -> float:
    return 0.0


class _frozen:
    """Context: the modules' parameters take no gradient (the critics during the actor step),
    restored to their previous state on exit."""

    def __init__(self, *modules: nn.Module) -> None:
        self.params = [p for m in modules for p in m.parameters()]

    def __enter__(self) -> None:
        self.saved = [p.requires_grad for p in self.params]
        for p in self.params:
            p.requires_grad_(False)

    def __exit__(self, *exc) -> None:
        for p, flag in zip(self.params, self.saved, strict=True):
            p.requires_grad_(flag)


def _translate_legacy_keys(state: Mapping[str, Any]) -> dict[str, Any]:
    """State dicts written before the auxiliary losses were modules: `collision_head`,
    `state_head` and `curl` (W, W_view) become `aux/collision`, `aux/state`, `aux/curl` and
    `aux/across_view`."""
    state = dict(state)
    if "collision_head" in state:
        state["aux/collision"] = {f"head.{k}": v for k, v in state.pop("collision_head").items()}
    if "state_head" in state:
        state["aux/state"] = {f"head.{k}": v for k, v in state.pop("state_head").items()}
    if "curl" in state:
        curl = state.pop("curl")
        state["aux/curl"] = {"W": curl["W"]}
        if "W_view" in curl:
            state["aux/across_view"] = {"W": curl["W_view"]}
    return state


def _jsonable(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _jsonable(v) for k, v in data.items()}
    if isinstance(data, tuple | list):
        return [_jsonable(v) for v in data]
    return data
