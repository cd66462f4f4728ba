"""`clamgen train-residual`: stage 2, the vision residual on the frozen base (paper, Table 2).

Differences from stage 1 (`clamgen.experiments.train`, whose loop this reuses):
- the agent is a `ResidualAgent` built around the base policy file's actor and critic;
- the collision penalty follows the curriculum (`env.collision_penalty`, paper: 0 until 30% of
  training, growing to 0.1 at 90%);
- with image observations, hindsight goals cannot be relabelled when a batch is sampled: the
  target drawn in the images must move too. Failed episodes are relabelled by reversible HER
  when they end, re-rendered with the target at the new goal in a separate process
  (`RerenderWorker`), and stored when the frames come back; learning does not wait.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym

from clamgen.agents.residual import ResidualAgent, ResidualConfig
from clamgen.agents.sac import SACAgent, SACConfig
from clamgen.envs import ENV_IDS
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import EnvConfig, LoopConfig, config_from_json, from_dict
from clamgen.experiments.train import Trainer, load_policy_agent
from clamgen.replay import ReplayConfig
from clamgen.replay.her import reversible_her
from clamgen.schedules import LinearRamp

RESIDUAL_POLICY_KIND = "residual-policy"
RESIDUAL_POLICY_KEYS = (
    "config",
    "critic",
    "actor",
    "base_actor",
    "base_critic",
    "normalizer",
    "log_alpha",
)


@dataclass(frozen=True)
class Stage2Config:
    """Everything `clamgen train-residual` needs; written as JSON into the run directory."""

    run_dir: Path = Path("runs/residual")
    """Directory for config, metrics, TensorBoard events and checkpoints."""
    base_policy: str = "base"
    """The stage-1 policy: `base` (shipped) or a policy file from `clamgen train`."""
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

    def __post_init__(self) -> None:
        images = self.agent.obs_source == "images"
        if images and self.env.num_views != self.agent.encoder.num_views:
            raise ValueError(
                f"env.num_views ({self.env.num_views}) must equal agent.encoder.num_views "
                f"({self.agent.encoder.num_views})"
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
        if not images and not self.env.include_obstacle_state:
            raise ValueError("agent.obs_source='obstacles' needs env.include_obstacle_state=True")


class Stage2Trainer(Trainer):
    """The stage-1 loop with a residual agent and re-rendered hindsight episodes."""

    policy_kind = RESIDUAL_POLICY_KIND
    policy_state_keys = RESIDUAL_POLICY_KEYS

    def __init__(self, config: Stage2Config) -> None:
        self._worker = None
        super().__init__(config)
        if config.image_her and config.agent.obs_source == "images":
            from clamgen.replay.rerender import RerenderWorker

            self._worker = RerenderWorker(
                num_views=config.env.num_views,
                image_size=config.env.image_size,
                synchronous=config.rerender_in_process,
            )

    def make_agent(self, probe: gym.Env) -> ResidualAgent:
        from clamgen.experiments.policies import resolve_policy_path

        base, _ = load_policy_agent(resolve_policy_path(self.config.base_policy))
        agent_config = dataclasses.replace(self.config.agent, seed=self.config.loop.seed)
        num_obstacles = (
            probe.unwrapped.num_obstacles if hasattr(probe.unwrapped, "num_obstacles") else 2
        )
        return ResidualAgent(agent_config, base, num_obstacles=num_obstacles)

    def store_episode(self, episode, env: gym.Env) -> None:
        self.buffer.add_episode(episode)
        if self._worker is None:
            if self.config.image_her:  # poses, not images: relabelled episodes need no render
                for extra in reversible_her(episode, env.unwrapped.compute_reward):
                    self.buffer.add_episode(extra)
            return
        obstacles = env.unwrapped.scene.obstacles
        for extra in reversible_her(episode, env.unwrapped.compute_reward):
            self._worker.submit(extra, obstacles)

    def _update(self):
        if self._worker is not None:
            for _, episode in self._worker.poll():
                self.buffer.add_episode(episode)
        return super()._update()

    def _rollout_metrics(self) -> dict[str, float]:
        metrics = super()._rollout_metrics()
        if self._worker is not None:
            metrics |= {key: float(value) for key, value in self._worker.stats.items()}
        return metrics

    def save_checkpoint(self) -> None:
        # Relabelled episodes still being rendered would be lost: wait for them first.
        if self._worker is not None:
            for _, episode in self._worker.drain(timeout=600):
                self.buffer.add_episode(episode)
        super().save_checkpoint()

    def policy_payload(self) -> dict:
        # The base's own config and sizes, so the file loads without the base policy file.
        return super().policy_payload() | {
            "base_config": dataclasses.asdict(self.agent.base.config),
            "action_dim": self.agent.action_dim,
        }

    def run(self, show_progress: bool = True):
        try:
            return super().run(show_progress)
        finally:
            if self._worker is not None:
                self._worker.close()


def load_residual_agent(path: Path) -> tuple[ResidualAgent, Stage2Config]:
    """The agent of a residual policy file and the config that trained it (the file carries the
    base's weights too, so the base policy file is not needed)."""
    payload = ckpt.load_torch(Path(path), RESIDUAL_POLICY_KIND)
    config: Stage2Config = config_from_json(payload["config"], Stage2Config)
    state = dict(payload["agent"])
    base_config = from_dict(SACConfig, payload["base_config"])
    obs_dim = int(state["normalizer"]["mean"].shape[0])
    base = SACAgent(base_config, obs_dim=obs_dim, action_dim=int(payload["action_dim"]))
    agent = ResidualAgent(config.agent, base)
    # Training-only parts a policy file leaves out keep their fresh values.
    fresh = agent.state_dict()
    for key in (
        "critic_target",
        "key_encoder",
        "base_critic_target",
        "collision_head",
        "curl",
        "num_updates",
    ):
        state.setdefault(key, fresh[key])
    try:
        agent.load_state_dict(state)
    except (RuntimeError, KeyError) as error:
        raise ckpt.CheckpointError(f"{path} does not match its own config: {error}") from error
    return agent, config
