"""`clamgen train`: goal-conditioned SAC with HER and reversible HER (paper, stage 1).

The loop, per iteration: every env takes one step with the current policy (uniform random
actions before `learning_starts`), finished episodes go into the replay buffer (which adds the
reversible-HER episodes of failed ones), then `updates_per_step` gradient updates per env step.
Metrics go to `metrics.csv` and TensorBoard; checkpoints resume exactly, including the episodes
in progress, after a crash (the last periodic checkpoint) or Ctrl-C (a checkpoint at once). A
resume drops the metrics logged after its checkpoint, so every (step, metric) pair is logged
once. Checkpoints survive a kill at any instant (`clamgen.experiments.checkpoint`).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

from clamgen.agents.sac import NonFiniteLossError, SACAgent, SACConfig
from clamgen.envs import ENV_IDS, ReachEnv
from clamgen.envs.reach_env import EnvState
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import (
    VALIDATION_SEEDS,
    EnvConfig,
    TrainConfig,
    config_from_json,
    config_to_json,
    from_dict,
)
from clamgen.experiments.evaluate import SACPolicy, evaluate, summarize
from clamgen.replay import (
    EpisodeRecorder,
    ReplayBuffer,
    available_memory_bytes,
    nbytes_required,
    obs_spec_from_space,
)
from clamgen.replay.buffer import BLOCK_BYTES, ReplayConfig
from clamgen.replay.pipeline import EpisodePipeline, HindsightConfig
from clamgen.sim.scene import Obstacles
from clamgen.sim.state import SimState
from clamgen.tasks.reach import Task

POLICY_NAME = "policy.pt"
# Successes of the last this many training episodes feed the progress bar's rate.
RECENT_EPISODES = 100
# Stream of the loop seed's generator that decides which episodes the teacher drives (apart
# from the replay-sampling stream, so that a run without a teacher draws exactly as before).
TEACHER_STREAM = 7


def make_env(config: EnvConfig, training: bool = False) -> gym.Env:
    """A training (`training`: with `config.training_collision_margin_m` and
    `config.collision_ends_episode`) or evaluation env.
    CLAMGen ids are built bare (their own 100-step truncation, no wrappers) so their full state
    can be checkpointed; other ids go through `gym.make`."""
    if config.env_id in ENV_IDS:
        spec = gym.spec(config.env_id)
        kwargs = {**spec.kwargs, **config.make_kwargs()}
        kwargs["max_episode_steps"] = spec.max_episode_steps
        if training:
            kwargs["collision_margin_m"] = config.training_collision_margin_m
            kwargs["collision_ends_episode"] = config.collision_ends_episode
        return ReachEnv(**kwargs)
    return gym.make(config.env_id)


METRICS_HEADER = ["step", "wall_time_s", "metric", "value"]


class MetricLogger:
    """Scalars to `metrics.csv` (long format: step, wall_time_s, metric, value) and TensorBoard.

    `resume_step` is the step of the checkpoint the run continues from (None: a fresh start).
    What was logged after it, by the attempt that died, is dropped: `metrics.csv` keeps its rows
    up to that step and TensorBoard hides later events (`purge_step`), so each (step, metric)
    pair appears once. A checkpoint is always written after every row of its step."""

    def __init__(self, run_dir: Path, resume_step: int | None) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.path = run_dir / "metrics.csv"
        truncate_metrics(self.path, -1 if resume_step is None else resume_step)
        self._file = self.path.open("a", newline="")
        self._csv = csv.writer(self._file)
        purge_step = 0 if resume_step is None else resume_step + 1
        self._tb = SummaryWriter(str(run_dir / "tensorboard"), purge_step=purge_step)

    def log(self, step: int, wall_time_s: float, metrics: dict[str, float]) -> None:
        for key, value in metrics.items():
            self._csv.writerow([step, f"{wall_time_s:.2f}", key, f"{value:.6g}"])
            self._tb.add_scalar(key, value, step)
        self._file.flush()

    def close(self) -> None:
        self._file.close()
        self._tb.close()


def truncate_metrics(path: Path, last_step: int) -> None:
    """Keep the header and the rows of steps <= `last_step` of a `metrics.csv` (replaced
    atomically; created with its header if missing)."""
    rows: list[list[str]] = []
    if path.exists():
        with path.open(newline="") as f:
            rows = [row for row in list(csv.reader(f))[1:] if row and _step(row) <= last_step]

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as f:
            csv.writer(f).writerows([METRICS_HEADER, *rows])

    ckpt.atomic_write(path, write)


def _step(row: list[str]) -> int:
    try:
        return int(row[0])
    except ValueError:  # a row cut short by a kill
        return 2**62


@dataclasses.dataclass
class Progress:
    """Counters that a checkpoint carries over."""

    env_steps: int = 0
    episodes: int = 0
    updates: int = 0
    updates_owed: float = 0.0
    wall_time_s: float = 0.0
    best_eval_success: float = -1.0
    teacher_episodes: int = 0
    """Training episodes driven by the teacher (`loop.teacher_fraction`)."""
    last_eval: dict[str, float] = dataclasses.field(default_factory=dict)
    """The latest evaluation summary, so that a resume at the end does not evaluate again."""


@dataclasses.dataclass(frozen=True)
class Stage:
    """What a training stage plugs into the shared loop (`Trainer`); stage 1 and stage 2
    differ only in this.

    The agent is anything with `act(obs, deterministic=False) -> actions`, `update(batch) ->
    metrics`, `state_dict()`, `load_state_dict(state)`, `policy_state_keys()` and
    `config.batch_size`.
    """

    make_agent: Callable[[gym.Env], Any]
    """The agent, sized by a probe env (seeded by the loop seed)."""
    hindsight: HindsightConfig
    """The relabelling the episode pipeline applies."""
    make_rerender: Callable[[], Any] | None = None
    """A re-rendering worker for relabelled image episodes (None: store them as they are)."""
    policy_kind: str = ckpt.POLICY_KIND
    """The `kind` written into exported policy files."""
    policy_extras: Callable[[Any], dict[str, Any]] | None = None
    """More entries for the policy file, from the agent."""
    before_start: Callable[[Trainer], None] | None = None
    """Run once on a fresh start, before the first step (not on a resume)."""


def joint_stage(config: TrainConfig) -> Stage:
    """Stage 1: SAC on joints and goal, HER at sample time and reversible HER at insert time."""

    def make_agent(probe: gym.Env) -> SACAgent:
        agent_config = dataclasses.replace(config.agent, seed=config.loop.seed)
        return SACAgent.from_spaces(agent_config, probe.observation_space, probe.action_space)

    return Stage(make_agent=make_agent, hindsight=hindsight_of(config.replay))


def hindsight_of(replay: ReplayConfig, reversible: bool | None = None) -> HindsightConfig:
    """The pipeline's relabelling from a replay config (`reversible` overrides its flag)."""
    return HindsightConfig(
        reversible=replay.reversible_her if reversible is None else reversible,
        her_ratio=replay.her_ratio,
        her_strategy=replay.her_strategy,
    )


class Trainer:
    """Holds envs, agent, episode pipeline and counters; `run()` trains until the budget is
    spent. What differs between stages comes in as a `Stage` (default: stage 1)."""

    def __init__(self, config: TrainConfig, stage: Stage | None = None) -> None:
        self.config = config
        self.stage = stage or joint_stage(config)
        loop = config.loop
        torch.set_num_threads(loop.torch_threads)
        self.run_dir = Path(config.run_dir)
        self.checkpoint_dir = self.run_dir / "checkpoints"
        self.checkpoints = ckpt.CheckpointStore(self.checkpoint_dir)
        self.envs = [make_env(config.env, training=True) for _ in range(config.env.num_envs)]
        self.eval_env = make_env(config.env)
        probe = self.envs[0]
        # The loop seed seeds everything, the agent included.
        self.agent = self.stage.make_agent(probe)
        self.memory_need_bytes = self._check_memory(probe)
        # The env's own terminal rule where it has one (a collision may end an episode);
        # otherwise the buffer derives it from the sparse reward.
        compute_terminated = getattr(probe.unwrapped, "compute_terminated", None)
        self.buffer = ReplayBuffer(
            config.replay,
            obs_spec_from_space(probe.observation_space),
            int(np.prod(probe.action_space.shape)),
            probe.unwrapped.compute_reward,
            compute_terminated,
        )
        rerender = self.stage.make_rerender() if self.stage.make_rerender else None
        self.pipeline = EpisodePipeline(
            self.buffer,
            self.stage.hindsight,
            probe.unwrapped.compute_reward,
            compute_terminated,
            rerender=rerender,
            n_step=config.replay.n_step,
            gamma=config.agent.gamma,
        )
        self.rng = np.random.default_rng(loop.seed)
        self.teacher_rng = np.random.default_rng([loop.seed, TEACHER_STREAM])
        # The teacher driving each env's current episode (None: the agent drives it).
        self.teachers: list[Any] = [None] * len(self.envs)
        self._teacher_policies = (
            [_make_teacher() for _ in self.envs] if loop.teacher_fraction > 0 else None
        )
        self.progress = Progress()
        self.recent_successes: deque[bool] = deque(maxlen=RECENT_EPISODES)
        self.obs: list[dict[str, np.ndarray]] = []
        self.recorders: list[EpisodeRecorder] = []
        self._resumed: bool | None = None  # set by start_or_resume()
        self.resumed_from_step: int | None = None

    def _check_memory(self, probe: gym.Env) -> int:
        """Print what the run needs at its peak (the replay, plus what saving or resuming a
        checkpoint holds besides it) and refuse to start when it would not fit."""
        replay = self.config.replay
        spec = obs_spec_from_space(probe.observation_space)
        action_dim = int(np.prod(probe.action_space.shape))
        replay_bytes = nbytes_required(replay, spec, action_dim)
        slot_bytes = replay_bytes // replay.capacity
        # Saving: the episodes in progress as arrays, one replay block being written (numpy's
        # zip writer copies in chunks of at most a block), the agent's state. Resuming: one
        # replay block read at a time, the agent's state read then copied into the networks.
        horizon = getattr(probe.unwrapped, "max_episode_steps", None) or 100
        episodes_bytes = len(self.envs) * (horizon + 1) * slot_bytes
        agent_bytes = _nbytes(self.agent.state_dict())
        checkpoint_bytes = 2 * min(BLOCK_BYTES, replay_bytes) + episodes_bytes + 2 * agent_bytes
        need = replay_bytes + checkpoint_bytes
        available = available_memory_bytes()
        print(
            f"memory: {need / 2**30:.2f} GiB at peak (replay {replay_bytes / 2**30:.2f} GiB, "
            f"checkpoint save/resume {checkpoint_bytes / 2**30:.2f} GiB); "
            f"{available / 2**30:.2f} GiB available"
        )
        if need > replay.max_memory_fraction * available:
            raise ValueError(
                f"this run needs {need / 2**30:.2f} GiB at peak (replay capacity "
                f"{replay.capacity}: {replay_bytes / 2**30:.2f} GiB), more than "
                f"{replay.max_memory_fraction:.0%} of the {available / 2**30:.2f} GiB available; "
                "lower replay.capacity"
            )
        return need

    # ------------------------------------------------------------------------ run
    def start_or_resume(self) -> bool:
        """Resume from the run directory's checkpoint if there is one; True if resumed.

        Idempotent: `run()` calls it, and a second call returns the first call's answer."""
        if self._resumed is not None:
            return self._resumed
        self._resumed = self._start_or_resume()
        if not self._resumed and self.stage.before_start is not None:
            self.stage.before_start(self)
        return self._resumed

    def _start_or_resume(self) -> bool:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        config_path = self.run_dir / "config.json"
        if self.checkpoints.exists():
            self._load_checkpoint()
            return True
        config_path.write_text(config_to_json(self.config))
        for i, env in enumerate(self.envs):
            obs, _ = env.reset(seed=self.config.loop.seed * 1000 + i)
            self.obs.append(obs)
            self.recorders.append(EpisodeRecorder(obs))
            self._choose_driver(i)
        self._apply_curriculum()
        return False

    def run(self, show_progress: bool = True) -> dict[str, float]:
        """Train to `loop.total_env_steps`; returns the last evaluation's summary. The
        re-rendering worker, if any, is stopped at the end however the run ends."""
        try:
            return self._run(show_progress)
        finally:
            self.pipeline.close()

    def _run(self, show_progress: bool) -> dict[str, float]:
        loop = self.config.loop
        resumed = self.start_or_resume()
        logger = MetricLogger(self.run_dir, self.resumed_from_step)
        bar = tqdm(
            total=loop.total_env_steps,
            initial=self.progress.env_steps,
            disable=not show_progress,
            unit="step",
            desc="resumed" if resumed else "training",
            dynamic_ncols=True,
        )
        start = time.perf_counter() - self.progress.wall_time_s
        last_eval: dict[str, float] = dict(self.progress.last_eval)
        train_metrics: dict[str, float] = {}
        self.stop_requested = False
        previous_handler = _install_interrupt_handler(self)
        try:
            while self.progress.env_steps < loop.total_env_steps:
                if self.stop_requested:
                    raise KeyboardInterrupt
                steps_before = self.progress.env_steps
                train_metrics = self.step() or train_metrics
                self.progress.wall_time_s = time.perf_counter() - start
                bar.update(self.progress.env_steps - steps_before)
                if self._crossed(steps_before, loop.log_every_steps):
                    rollout = self._rollout_metrics()
                    logger.log(
                        self.progress.env_steps, self.progress.wall_time_s, train_metrics | rollout
                    )
                    bar.set_postfix(
                        success=f"{rollout.get('rollout/success_rate', 0):.2f}",
                        sps=f"{self.progress.env_steps / max(self.progress.wall_time_s, 1e-9):.0f}",
                    )
                if self._crossed(steps_before, loop.eval_every_steps):
                    last_eval = self.evaluate()
                    logger.log(self.progress.env_steps, self.progress.wall_time_s, last_eval)
                    if self._stop_early(last_eval):
                        break
                if self._crossed(steps_before, loop.checkpoint_every_steps):
                    self.save_checkpoint()
        except KeyboardInterrupt:
            self.save_checkpoint()
            self.checkpoints.wait()
            bar.close()
            logger.close()
            print(f"\ninterrupted: checkpoint saved in {self.checkpoint_dir}; run again to resume")
            raise
        except NonFiniteLossError as error:
            self.checkpoints.wait()
            bar.close()
            logger.close()
            raise SystemExit(
                f"training stopped: {error}. The last good checkpoint in {self.checkpoint_dir} "
                "is intact (nothing was saved after the failure)."
            ) from error
        finally:
            _restore_interrupt_handler(previous_handler)
        bar.close()
        if not last_eval or last_eval.get("eval/env_steps") != self.progress.env_steps:
            last_eval = self.evaluate()
            logger.log(self.progress.env_steps, self.progress.wall_time_s, last_eval)
        self.save_checkpoint()
        self.checkpoints.wait()
        self.export_policy(self.run_dir / POLICY_NAME)
        logger.close()
        return last_eval

    def _crossed(self, before: int, every: int) -> bool:
        return every > 0 and before // every < self.progress.env_steps // every

    def _stop_early(self, metrics: dict[str, float]) -> bool:
        target = self.config.loop.stop_at_success
        return target is not None and metrics["eval/success_rate"] >= target

    # ------------------------------------------------------------------- pieces
    def step(self) -> dict[str, float] | None:
        """One iteration: a step in every env, then the updates it pays for (their metrics,
        None before learning starts). Call `start_or_resume()` first."""
        self._collect_step()
        return self._update()

    def _collect_step(self) -> None:
        """One step in every env; finished episodes go to the buffer."""
        loop = self.config.loop
        num_envs = len(self.envs)
        if self.progress.env_steps < loop.learning_starts:
            actions = self.rng.uniform(-1.0, 1.0, (num_envs, *self.envs[0].action_space.shape))
        else:
            batch = {key: np.stack([o[key] for o in self.obs]) for key in self.obs[0]}
            actions = self.agent.act(batch)
        for i, teacher in enumerate(self.teachers):
            if teacher is not None:
                actions[i] = teacher.act(self.obs[i])
        for i, env in enumerate(self.envs):
            obs, _, terminated, truncated, info = env.step(actions[i])
            self.recorders[i].add(actions[i], obs, info)
            if terminated or truncated:
                episode = self.recorders[i].episode()
                if self.teachers[i] is not None:
                    episode = dataclasses.replace(episode, demonstration=True)
                self.pipeline.store(episode, _obstacles(env))
                if self.teachers[i] is None:  # the rollout success rate is the agent's
                    self.recent_successes.append(not episode.failed)
                else:
                    self.progress.teacher_episodes += 1
                self.progress.episodes += 1
                obs, _ = env.reset()
                self.recorders[i] = EpisodeRecorder(obs)
                self._choose_driver(i)  # the teacher plans from the env's new task
            self.obs[i] = obs
        self.progress.env_steps += num_envs
        self._apply_curriculum()

    def _choose_driver(self, i: int) -> None:
        """Decide who drives env i's new episode: the teacher with `loop.teacher_probability`
        (when it finds a plan), otherwise the agent."""
        self.teachers[i] = None
        if self._teacher_policies is None:
            return
        progress = self.progress.env_steps / self.config.loop.total_env_steps
        if self.teacher_rng.random() >= self.config.loop.teacher_probability(progress):
            return
        teacher = self._teacher_policies[i]
        teacher.reset(self.envs[i])
        if teacher.last_plan_succeeded:
            self.teachers[i] = teacher

    def _apply_curriculum(self) -> None:
        progress = self.progress.env_steps / self.config.loop.total_env_steps
        penalty = self.config.env.collision_penalty(progress)
        for env in (*self.envs, self.eval_env):
            if hasattr(env.unwrapped, "set_collision_penalty"):
                env.unwrapped.set_collision_penalty(penalty)

    def _update(self) -> dict[str, float] | None:
        loop = self.config.loop
        self.pipeline.collect()  # re-rendered episodes that came back
        if self.progress.env_steps < loop.learning_starts or len(self.buffer) == 0:
            return None
        self.progress.updates_owed += len(self.envs) * loop.updates_per_step
        metrics = None
        while self.progress.updates_owed >= 1.0:
            batch = self.pipeline.sample(self.agent.config.batch_size, self.rng)
            metrics = self.agent.update(batch)
            self.progress.updates += 1
            self.progress.updates_owed -= 1.0
        return metrics

    def _rollout_metrics(self) -> dict[str, float]:
        wall = max(self.progress.wall_time_s, 1e-9)
        metrics = {
            "rollout/episodes": float(self.progress.episodes),
            "rollout/updates": float(self.progress.updates),
            "rollout/env_steps_per_s": self.progress.env_steps / wall,
            "rollout/replay_transitions": float(len(self.buffer)),
        }
        if self._teacher_policies is not None:
            metrics["rollout/teacher_episodes"] = float(self.progress.teacher_episodes)
        if self.recent_successes:
            metrics["rollout/success_rate"] = float(np.mean(self.recent_successes))
        return metrics | self.pipeline.metrics()

    def evaluate(self) -> dict[str, float]:
        """Deterministic policy on the first `num_eval_episodes` validation seeds (never the
        tables' test seeds: whatever is chosen by watching this must not leak into them)."""
        seeds = VALIDATION_SEEDS.seeds(self.config.loop.num_eval_episodes)
        records = evaluate(self.eval_env, SACPolicy(self.agent), seeds)
        summary = {f"eval/{k}": v for k, v in summarize(records).items()}
        summary["eval/env_steps"] = float(self.progress.env_steps)
        self.progress.best_eval_success = max(
            self.progress.best_eval_success, summary["eval/success_rate"]
        )
        self.progress.last_eval = summary
        return summary

    # --------------------------------------------------------------- checkpoints
    def save_checkpoint(self) -> None:
        """Write and publish the resumable state (`checkpoint.CheckpointStore.save`; a large
        replay is written in the background, `self.checkpoints.wait()` waits for it)."""
        # Relabelled episodes still being re-rendered would be lost: store them first.
        self.pipeline.flush()
        stamp = self.progress.env_steps
        arrays: dict[str, np.ndarray] = {}
        for i, env in enumerate(self.envs):
            arrays |= {f"env{i}/{k}": v for k, v in _env_snapshot(env).items()}
            arrays |= {f"recorder{i}/{k}": v for k, v in self.recorders[i].arrays().items()}
        payload = {
            "format": ckpt.FORMAT,
            "kind": ckpt.TRAINING_KIND,
            "stamp": stamp,
            "config": config_to_json(self.config),
            "agent": self.agent.state_dict(),
            "progress": dataclasses.asdict(self.progress),
            "rng": json.dumps(self.rng.bit_generator.state),
            "teacher_rng": json.dumps(self.teacher_rng.bit_generator.state),
            "recent_successes": [bool(s) for s in self.recent_successes],
        }
        self.checkpoints.save(payload, arrays, self.buffer)

    def _check_checkpoint(self, payload: dict[str, Any], path: Path) -> None:
        saved = config_from_json(payload["config"], type(self.config))
        if _without_budget(saved) != _without_budget(self.config):
            raise ckpt.CheckpointError(
                f"{path} was written with a different configuration; resume with the run's own "
                f"config ({self.run_dir / 'config.json'}) or choose a new run_dir. Only "
                "loop.total_env_steps may change on resume."
            )

    def _load_checkpoint(self) -> None:
        loaded = self.checkpoints.load(self.buffer, self._check_checkpoint)
        payload, arrays = loaded.payload, loaded.arrays
        ckpt.load_agent_state(self.agent, payload["agent"], loaded.path)
        self.progress = Progress(**payload["progress"])
        self.resumed_from_step = self.progress.env_steps
        self.rng.bit_generator.state = json.loads(payload["rng"])
        if "teacher_rng" in payload:
            self.teacher_rng.bit_generator.state = json.loads(payload["teacher_rng"])
        # Episodes in progress continue under the agent (a teacher's plan is not saved).
        self.recent_successes.extend(payload["recent_successes"])
        self.obs, self.recorders = [], []
        for i, env in enumerate(self.envs):
            _restore_env(env, _sub(arrays, f"env{i}/"))
            recorder = EpisodeRecorder.from_arrays(_sub(arrays, f"recorder{i}/"))
            self.recorders.append(recorder)
            self.obs.append({k[4:]: v[-1] for k, v in recorder.arrays().items() if k[:4] == "obs/"})
        (self.run_dir / "config.json").write_text(config_to_json(self.config))
        self._apply_curriculum()

    def policy_payload(self) -> dict[str, Any]:
        """What a policy file holds: what acting (and stage 2) needs, no optimiser or replay
        state; the stage's extras."""
        state = self.agent.state_dict()
        extras = self.stage.policy_extras(self.agent) if self.stage.policy_extras else {}
        return {
            "format": ckpt.FORMAT,
            "kind": self.stage.policy_kind,
            "config": config_to_json(self.config),
            "env_steps": self.progress.env_steps,
            "agent": {k: state[k] for k in self.agent.policy_state_keys()},
            **extras,
        }

    def export_policy(self, path: Path) -> None:
        """Write the small policy file (`policy_payload`)."""
        ckpt.save_torch(path, self.policy_payload())


def load_policy_agent(path: Path, payload: dict | None = None) -> tuple[SACAgent, TrainConfig]:
    """The SAC agent of a policy file (`export_policy`) and the config that trained it.
    `payload`: the file's contents when already read."""
    if payload is None or payload.get("kind") != ckpt.POLICY_KIND:
        payload = ckpt.load_torch(Path(path), ckpt.POLICY_KIND)
    config = config_from_json(payload["config"])
    state = payload["agent"]
    agent_config = from_dict(SACConfig, state["config"])
    try:
        # Sized by the actor's weights: its first layer reads the observation, its last gives
        # a mean and a log std per action dimension.
        obs_dim = int(state["actor"]["trunk.0.weight"].shape[1])
        layers = [k for k in state["actor"] if k.startswith("trunk.") and k.endswith(".weight")]
        last = max(layers, key=lambda key: int(key.split(".")[1]))
        action_dim = int(state["actor"][last].shape[0]) // 2
        agent = SACAgent(agent_config, obs_dim=obs_dim, action_dim=action_dim)
        agent.load_policy_state(state)
    except (RuntimeError, KeyError) as error:
        raise ckpt.CheckpointError(f"{path} does not match its own config: {error}") from error
    return agent, config


def _make_teacher() -> Any:
    """The RRT planner with the full scene model (needs OMPL: a one-line error otherwise)."""
    from clamgen.baselines.rrt import RRTPolicy, _ompl

    _ompl()
    return RRTPolicy()


def _obstacles(env: gym.Env) -> Any:
    """The obstacles of `env`'s current task (what re-rendering needs), or None."""
    task = getattr(env.unwrapped, "task", None)
    return getattr(task, "obstacles", None)


def _install_interrupt_handler(trainer: Trainer):
    """First Ctrl-C: finish the current iteration, checkpoint, stop. Second: stop at once."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):
        if trainer.stop_requested:
            raise KeyboardInterrupt
        trainer.stop_requested = True
        print("\nstopping after this step to write a checkpoint (Ctrl-C again to abort)")

    return signal.signal(signal.SIGINT, handler)


def _restore_interrupt_handler(previous) -> None:
    if previous is not None:
        signal.signal(signal.SIGINT, previous)


def _without_budget(config: TrainConfig) -> str:
    loop = dataclasses.replace(config.loop, total_env_steps=1, stop_at_success=None)
    return config_to_json(dataclasses.replace(config, loop=loop, run_dir=Path(".")))


def _nbytes(state: Any) -> int:
    """Bytes of the tensors and arrays in a (nested) state dict."""
    if isinstance(state, torch.Tensor):
        return state.numel() * state.element_size()
    if isinstance(state, np.ndarray):
        return state.nbytes
    if isinstance(state, dict):
        return sum(_nbytes(v) for v in state.values())
    if isinstance(state, (list, tuple)):
        return sum(_nbytes(v) for v in state)
    return 0


def _sub(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    return {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)}


def _env_snapshot(env: gym.Env) -> dict[str, np.ndarray]:
    """Arrays that restore a CLAMGen env's episode exactly (empty for other envs)."""
    unwrapped = env.unwrapped
    if not isinstance(unwrapped, ReachEnv):
        return {}
    state = unwrapped.get_state()
    task = state.task
    arrays = {
        "joints": state.sim.joints,
        "target": state.sim.target_position_m,
        "kinds": state.sim.obstacles.kinds,
        "positions": state.sim.obstacles.positions_m,
        "half_sizes": state.sim.obstacles.half_sizes_m,
        "velocity": state.target_velocity_mps,
        "num_steps": np.array(state.num_steps),
        "rng": np.array(json.dumps(unwrapped.np_random.bit_generator.state)),
        "previous_action": state.previous_action,
    }
    if task is not None:
        arrays |= {
            "task/start_joints": task.start_joints,
            "task/target": task.target_position_m,
            "task/velocity": task.target_velocity_mps,
            "task/speed": np.array(json.dumps(task.speed)),
        }
    return arrays


def _restore_env(env: gym.Env, arrays: dict[str, np.ndarray]) -> None:
    unwrapped = env.unwrapped
    if not arrays or not isinstance(unwrapped, ReachEnv):
        env.reset()  # a foreign env: its episode in progress is lost, as documented
        return
    obstacles = Obstacles(arrays["kinds"], arrays["positions"], arrays["half_sizes"])
    task = None
    if "task/start_joints" in arrays:
        task = Task(
            arrays["task/start_joints"],
            arrays["task/target"],
            arrays["task/velocity"],
            obstacles,
            json.loads(str(arrays["task/speed"])),
        )
    unwrapped.reset()  # initialises np_random; everything is then overwritten
    unwrapped.np_random.bit_generator.state = json.loads(str(arrays["rng"]))
    sim = SimState(arrays["joints"], arrays["target"], obstacles)
    previous = arrays.get("previous_action")  # absent from checkpoints before it existed
    state = EnvState(sim, arrays["velocity"], int(arrays["num_steps"]), task, previous)
    unwrapped.set_state(state)


def train(config: TrainConfig, show_progress: bool = True) -> dict[str, Any]:
    """Train (or resume) and return the final evaluation summary."""
    return Trainer(config).run(show_progress=show_progress)
