"""`clamgen train-residual`: stage 2, the vision residual on the frozen base (paper, Table 2).

Differences from stage 1 (`clamgen.experiments.train`, whose loop this reuses):
- the agent is a `ResidualAgent` built around the base policy file's actor and critic;
- the collision penalty follows the curriculum (`env.collision_penalty`, paper: 0 until 30% of
  training, growing to 0.1 at 90%);
- with image observations, hindsight goals cannot be relabelled when a batch is sampled: the
  target drawn in the images must move too. Failed episodes are relabelled by reversible HER
  when they end, re-rendered with the target at the new goal in a separate process
  (`RerenderWorker`), and stored when the frames come back; learning does not wait.
- optionally (`pretrain.scenes > 0`, for image-only agents) the encoder is first trained to
  read the joints and the goal from the images of random scenes (`EncoderPretrainConfig`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from clamgen.agents.residual import ResidualAgent, ResidualConfig
from clamgen.agents.sac import SACAgent, SACConfig
from clamgen.envs import ENV_IDS
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import EnvConfig, LoopConfig, config_from_json, from_dict
from clamgen.experiments.train import Stage, Trainer, hindsight_of, load_policy_agent, make_env
from clamgen.replay import ReplayConfig
from clamgen.schedules import LinearRamp

RESIDUAL_POLICY_KIND = "residual-policy"


@dataclass(frozen=True)
class EncoderPretrainConfig:
    """Supervised encoder pretraining before RL, for image agents (our addition; the paper
    trains end to end). Random scenes (random joints and goal, the environment's resets) are
    rendered and the encoder with the state head regresses joints and goal from them
    (`ResidualAgent.pretrain_encoder`). In RL the replay holds few distinct goals, and the
    2 cm target was not found from it (results/image_only/README.md); thousands of random
    scenes teach the encoder where the target is in a few minutes."""

    scenes: int = 0
    """Random scenes rendered for pretraining; 0 switches pretraining off."""
    held_out_scenes: int = 200
    """Further scenes on which the goal error is measured after pretraining."""
    steps: int = 3_000
    """Gradient steps (batches of random crops)."""
    batch_size: int = 64
    """Scenes per step."""
    lr: float = 1e-3
    """Adam learning rate (a fresh optimiser, not the agent's)."""
    seed: int = 1_000_000
    """Reset seed of the first scene; far from the training and evaluation seeds."""

    def __post_init__(self) -> None:
        if self.scenes < 0 or self.held_out_scenes < 0:
            raise ValueError("pretrain.scenes and pretrain.held_out_scenes must be >= 0")
        if self.steps < 1 or self.batch_size < 1 or not self.lr > 0:
            raise ValueError("pretrain.steps, pretrain.batch_size must be >= 1 and lr > 0")


@dataclass(frozen=True)
class Stage2Config:
    """Everything `clamgen train-residual` needs; written as JSON into the run directory."""

    run_dir: Path = Path("runs/residual")
    """Directory for config, metrics, TensorBoard events and checkpoints."""
    base_policy: str = "base"
    """The stage-1 policy: `base` (shipped) or a policy file from `clamgen train`."""
    init_policy: str = ""
    """Beyond the paper: a residual policy (a shipped one by name, e.g. `residual-3views`, or
    the file of `clamgen distill`'s student or a `train-residual` run) whose networks the agent
    starts from instead of fresh ones, for RL fine-tuning; its agent must have this run's
    network shapes (see `agent.freeze_encoder`, `agent.critic_first_updates`,
    `agent.anchor_weight`). "": fresh networks (the paper)."""
    image_her: bool = True
    """Reversible HER for image observations, re-rendered in a worker process ("no HER": off)."""
    rerender_in_process: bool = False
    """Re-render in the training process instead of a worker (debugging, tests)."""
    env: EnvConfig = field(
        default_factory=lambda: EnvConfig(
            env_id=ENV_IDS[1],
            num_views=2,
            image_size=72,
            obs_mode="both",
            collision_penalty=LinearRamp(0.3, 0.9, 0.0, 0.1),
        )
    )
    """Environment settings (ReachObstacles, views, stored image size, curriculum)."""
    agent: ResidualConfig = field(default_factory=ResidualConfig)
    """Residual agent settings (the encoder's image size is the crop of env.image_size)."""
    replay: ReplayConfig = field(
        default_factory=lambda: ReplayConfig(capacity=200_000, her_ratio=0.0, reversible_her=False)
    )
    """Replay settings. With images, sample-time HER must stay off (her_ratio 0, reversible_her
    False): relabelled episodes come re-rendered from the worker instead."""
    loop: LoopConfig = field(default_factory=LoopConfig)
    """Training loop settings."""
    pretrain: EncoderPretrainConfig = field(default_factory=EncoderPretrainConfig)
    """Supervised encoder pretraining before RL (off by default)."""

    def __post_init__(self) -> None:
        images = self.agent.obs_source == "images"
        views = self.env.num_views * (2 if self.env.zoom_views else 1)
        if images and views != self.agent.encoder.num_views:
            zoom = " x 2 with env.zoom_views" if self.env.zoom_views else ""
            raise ValueError(
                f"env.num_views ({self.env.num_views}{zoom}) must equal "
                f"agent.encoder.num_views ({self.agent.encoder.num_views})"
            )
        if images and self.env.image_size != self.agent.stored_image_size:
            raise ValueError(
                f"env.image_size ({self.env.image_size}) must be the encoder's crop plus padding "
                f"({self.agent.encoder.image_size} + 2 x {self.agent.crop_padding} = "
                f"{self.agent.stored_image_size})"
            )
        if images and (self.replay.her_ratio > 0 or self.replay.reversible_her):
            raise ValueError(
                "with image observations, sample-time HER would pair images with goals they do "
                "not show: set replay.her_ratio=0 and replay.reversible_her=False (image_her "
                "re-renders relabelled episodes instead)"
            )
        if self.pretrain.scenes > 0 and not images:
            raise ValueError("pretrain.scenes > 0 needs image observations (agent.obs_source)")
        if not images and not self.env.include_obstacle_state:
            raise ValueError("agent.obs_source='obstacles' needs env.include_obstacle_state=True")
        if self.agent.previous_action and not self.env.previous_action:
            raise ValueError("agent.previous_action needs env.previous_action=True")
        if self.init_policy and self.agent.warmup_updates > 0:
            raise ValueError(
                "init_policy with agent.warmup_updates > 0 would first clone the base policy "
                "over the started one: set agent.warmup_updates=0"
            )


def residual_stage(config: Stage2Config) -> Stage:
    """What stage 2 plugs into the shared training loop: the residual agent on the base policy
    file's actor and critic; reversible HER once per failed episode, re-rendered in a worker
    process for image observations; the base's config in the policy file; optional encoder
    pretraining on a fresh start."""
    images = config.agent.obs_source == "images"

    def make_agent(probe: gym.Env) -> ResidualAgent:
        base, _ = load_policy_agent(ckpt.resolve_policy_path(config.base_policy))
        agent_config = dataclasses.replace(config.agent, seed=config.loop.seed)
        num_obstacles = getattr(probe.unwrapped, "num_obstacles", 2)
        agent = ResidualAgent(agent_config, base, num_obstacles=num_obstacles)
        if config.init_policy:
            start_from_policy(agent, ckpt.resolve_policy_path(config.init_policy))
        return agent

    def make_rerender():
        from clamgen.replay.rerender import RerenderWorker

        if config.env.zoom_views:
            raise ValueError(
                "image_her re-renders the views only, not env.zoom_views: train zoomed "
                "students by distillation, or set image_her=False"
            )

        return RerenderWorker(
            num_views=config.env.num_views,
            image_size=config.env.image_size,
            synchronous=config.rerender_in_process,
            depth_noise_m=config.env.depth_noise_m,
            seed=config.loop.seed,
        )

    def policy_extras(agent: ResidualAgent) -> dict:
        # The base's own config and sizes, so the file loads without the base policy file.
        base_config = dataclasses.asdict(agent.base.config)
        return {"base_config": base_config, "action_dim": agent.action_dim}

    # One relabelling, whichever flag asks for it: with images, image_her (re-rendered); with
    # obstacle poses, image_her or replay.reversible_her (nothing to re-render).
    reversible = config.image_her or config.replay.reversible_her
    return Stage(
        make_agent=make_agent,
        hindsight=hindsight_of(config.replay, reversible=reversible),
        make_rerender=make_rerender if images and config.image_her else None,
        policy_kind=RESIDUAL_POLICY_KIND,
        policy_extras=policy_extras,
        before_start=pretrain_encoder if config.pretrain.scenes > 0 else None,
    )


class Stage2Trainer(Trainer):
    """The shared training loop with the residual stage plugged in (nothing overridden)."""

    def __init__(self, config: Stage2Config) -> None:
        if config.agent.actor_components > 1:
            raise ValueError(
                "agent.actor_components > 1 is for distilled students (clamgen distill); "
                "RL trains a single Gaussian"
            )
        if config.agent.previous_action and (config.image_her or config.replay.reversible_her):
            raise ValueError(
                "agent.previous_action with reversible HER: a time-reversed episode's states "
                "would keep the forward previous actions; set replay.reversible_her=False and "
                "image_her=False"
            )
        super().__init__(config, residual_stage(config))


def pretrain_encoder(trainer: Trainer) -> dict[str, float]:
    """Render random scenes, pretrain the trainer's agent's encoder on them, and write
    `pretrain.json` (goal and joint errors on held-out scenes, before and after) into the run
    directory."""
    config, agent = trainer.config, trainer.agent
    cfg = config.pretrain
    env = make_env(config.env)
    try:
        scenes = _render_scenes(env, cfg.seed, cfg.scenes, "pretrain: rendering")
        held_out = _render_scenes(env, cfg.seed + cfg.scenes, cfg.held_out_scenes, None)
    finally:
        env.close()
    before = _state_errors(agent, held_out)
    start = time.perf_counter()
    with tqdm(total=cfg.steps, desc="pretrain: encoder", unit="step") as bar:

        def on_step(loss: float) -> None:
            bar.update()
            bar.set_postfix(loss=f"{loss:.3f}", refresh=False)

        loss = agent.pretrain_encoder(scenes, cfg.steps, cfg.batch_size, cfg.lr, on_step)
    summary = {
        "scenes": cfg.scenes,
        "steps": cfg.steps,
        "seconds": round(time.perf_counter() - start, 1),
        "final_loss": loss,
        **{f"before/{k}": v for k, v in before.items()},
        **{f"after/{k}": v for k, v in _state_errors(agent, held_out).items()},
    }
    (trainer.run_dir / "pretrain.json").write_text(json.dumps(summary, indent=2) + "\n")
    print("pretrain:", json.dumps(summary))
    return summary


def start_from_policy(agent: ResidualAgent, path: Path) -> None:
    """`agent.start_from` the agent state of the residual policy file at `path`; a
    CheckpointError in one line when the file's networks do not fit the agent."""
    payload = ckpt.load_torch(path, RESIDUAL_POLICY_KIND)
    try:
        agent.start_from(payload["agent"])
    except (RuntimeError, KeyError) as error:
        first = str(error).strip().splitlines()[0]
        raise ckpt.CheckpointError(
            f"init_policy {path} does not fit this run's agent config: {first}"
        ) from error


def load_residual_agent(
    path: Path, payload: dict | None = None
) -> tuple[ResidualAgent, Stage2Config]:
    """The agent of a residual policy file and the config that trained it (the file carries the
    base's weights too, so the base policy file is not needed). `payload`: the file's contents
    when already read."""
    if payload is None or payload.get("kind") != RESIDUAL_POLICY_KIND:
        payload = ckpt.load_torch(Path(path), RESIDUAL_POLICY_KIND)
    config: Stage2Config = config_from_json(payload["config"], Stage2Config)
    state = dict(payload["agent"])
    base_config = from_dict(SACConfig, payload["base_config"])
    obs_dim = int(state["normalizer"]["mean"].shape[0])
    base = SACAgent(base_config, obs_dim=obs_dim, action_dim=int(payload["action_dim"]))
    agent = ResidualAgent(config.agent, base)
    try:  # the training-only parts a policy file leaves out keep their fresh values
        agent.load_state_dict(state, policy_only=True)
    except (RuntimeError, KeyError) as error:
        raise ckpt.CheckpointError(f"{path} does not match its own config: {error}") from error
    return agent, config


def _render_scenes(env: gym.Env, seed: int, count: int, desc: str | None) -> dict[str, np.ndarray]:
    """Observations of `count` resets (seeds seed, seed + 1, ...), stacked per key."""
    observations = [
        env.reset(seed=seed + i)[0] for i in tqdm(range(count), desc=desc, disable=desc is None)
    ]
    if not observations:
        return {}
    return {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}


def _state_errors(agent: ResidualAgent, scenes: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean goal distance (m) and joint error (rad) of the state head on `scenes`, and the goal
    distance of always guessing their mean goal."""
    if not scenes:
        return {}
    predicted = agent.predict_state(scenes)
    goal = scenes["desired_goal"]
    return {
        "goal_error_m": float(np.linalg.norm(predicted[:, 6:] - goal, axis=1).mean()),
        "joint_error_rad": float(np.abs(predicted[:, :6] - scenes["observation"]).mean()),
        "mean_goal_guess_error_m": float(np.linalg.norm(goal - goal.mean(0), axis=1).mean()),
    }
