"""Training loop: run directory contents, seeded determinism, exact resume, failure modes."""

import dataclasses
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
import torch

from clamgen.agents.sac import NonFiniteLossError, SACConfig
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import (
    EnvConfig,
    LoopConfig,
    TrainConfig,
    config_from_json,
    config_to_json,
    load_preset,
    parse_assignments,
)
from clamgen.experiments.train import (
    POLICY_NAME,
    Trainer,
    load_policy_agent,
)
from clamgen.replay import ReplayConfig
from clamgen.schedules import LinearRamp


def tiny_config(run_dir: Path, total: int = 240, **loop) -> TrainConfig:
    loop_config = LoopConfig(
        total_env_steps=total,
        learning_starts=80,
        updates_per_step=0.5,
        eval_every_steps=0,
        num_eval_episodes=3,
        checkpoint_every_steps=0,
        log_every_steps=40,
        seed=3,
        torch_threads=1,
    )
    return TrainConfig(
        run_dir=run_dir,
        env=EnvConfig(num_envs=2),
        agent=SACConfig(hidden_sizes=(32, 32), batch_size=32),
        replay=ReplayConfig(capacity=5_000),
        loop=dataclasses.replace(loop_config, **loop),
    )


def params(agent) -> list[torch.Tensor]:
    return [p.detach().clone() for p in (*agent.actor.parameters(), *agent.critic.parameters())]


def test_run_directory_has_config_metrics_events_checkpoint_and_policy(tmp_path):
    config = tiny_config(tmp_path / "run")
    summary = Trainer(config).run(show_progress=False)
    run = config.run_dir
    assert config_from_json((run / "config.json").read_text()) == config
    metrics = (run / "metrics.csv").read_text().splitlines()
    assert metrics[0] == "step,wall_time_s,metric,value"
    names = {line.split(",")[2] for line in metrics[1:]}
    assert {"train/critic_loss", "train/alpha", "rollout/episodes", "eval/success_rate"} <= names
    assert any((run / "tensorboard").iterdir())
    assert ckpt.latest_state_path(run / "checkpoints").exists()
    assert 0.0 <= summary["eval/success_rate"] <= 1.0
    agent, loaded_config = load_policy_agent(run / POLICY_NAME)
    assert loaded_config == config
    obs = {"observation": np.zeros(6, np.float32), "desired_goal": np.full(3, 0.5, np.float32)}
    assert agent.act(obs, deterministic=True).shape == (6,)


def test_seeded_training_is_deterministic(tmp_path):
    a = Trainer(tiny_config(tmp_path / "a"))
    a.run(show_progress=False)
    b = Trainer(tiny_config(tmp_path / "b"))
    b.run(show_progress=False)
    for x, y in zip(params(a.agent), params(b.agent), strict=True):
        torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_resume_continues_identically(tmp_path):
    straight = Trainer(tiny_config(tmp_path / "straight", total=240))
    straight.run(show_progress=False)
    first_half = Trainer(tiny_config(tmp_path / "resumed", total=120))
    first_half.run(show_progress=False)
    resumed = Trainer(tiny_config(tmp_path / "resumed", total=240))
    assert resumed.start_or_resume()
    assert resumed.progress.env_steps == 120
    resumed.run(show_progress=False)
    assert resumed.progress.updates == straight.progress.updates
    assert resumed.progress.episodes == straight.progress.episodes
    for x, y in zip(params(straight.agent), params(resumed.agent), strict=True):
        torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_resume_refuses_a_different_configuration(tmp_path):
    Trainer(tiny_config(tmp_path / "run", total=80)).run(show_progress=False)
    changed = dataclasses.replace(
        tiny_config(tmp_path / "run"), agent=SACConfig(hidden_sizes=(16,), batch_size=32)
    )
    with pytest.raises(ckpt.CheckpointError, match="different configuration"):
        Trainer(changed).start_or_resume()


def test_nan_loss_stops_with_a_clear_message_and_keeps_the_last_checkpoint(tmp_path):
    config = tiny_config(tmp_path / "run", total=200, checkpoint_every_steps=100)
    trainer = Trainer(config)
    real_update = trainer.agent.update

    def update(batch):
        if trainer.progress.env_steps > 150:
            raise NonFiniteLossError("train/critic_loss is nan at update 99")
        return real_update(batch)

    trainer.agent.update = update
    with pytest.raises(SystemExit, match=r"critic_loss is nan.*intact"):
        trainer.run(show_progress=False)
    saved = ckpt.load_torch(
        ckpt.latest_state_path(config.run_dir / "checkpoints"), ckpt.TRAINING_KIND
    )
    assert saved["stamp"] == 100


def test_missing_truncated_and_foreign_checkpoints_are_named(tmp_path):
    with pytest.raises(ckpt.CheckpointError, match="not found"):
        load_policy_agent(tmp_path / "nope.pt")
    config = tiny_config(tmp_path / "run", total=80)
    Trainer(config).run(show_progress=False)
    policy = config.run_dir / POLICY_NAME
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(policy.read_bytes()[:1000])
    with pytest.raises(ckpt.CheckpointError, match="truncated"):
        load_policy_agent(truncated)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ckpt.CheckpointError, match="not a clamgen checkpoint"):
        load_policy_agent(foreign)
    with pytest.raises(ckpt.CheckpointError, match="expected a 'sac-policy'"):
        load_policy_agent(ckpt.latest_state_path(config.run_dir / "checkpoints"))
    # A policy file whose weights do not match its config.
    payload = torch.load(policy, weights_only=True)
    payload["agent"]["actor"] = {k: v[:1] for k, v in payload["agent"]["actor"].items()}
    mismatched = tmp_path / "mismatched.pt"
    torch.save(payload, mismatched)
    with pytest.raises(ckpt.CheckpointError, match="does not match"):
        load_policy_agent(mismatched)


def test_interrupt_saves_a_checkpoint_that_resumes(tmp_path):
    config = tiny_config(tmp_path / "run", total=200)
    trainer = Trainer(config)
    real_collect = trainer._collect_step

    def collect():
        real_collect()
        if trainer.progress.env_steps == 140:
            os.kill(os.getpid(), signal.SIGINT)  # what Ctrl-C sends

    trainer._collect_step = collect
    with pytest.raises(KeyboardInterrupt):
        trainer.run(show_progress=False)
    resumed = Trainer(config)
    assert resumed.start_or_resume()
    assert resumed.progress.env_steps == 140
    resumed.run(show_progress=False)
    assert resumed.progress.env_steps == 200


def test_presets_load_and_config_round_trips_through_json():
    config = load_preset("base")
    assert config.env.env_id == "CLAMGen/Reach-v0"
    assert config_from_json(config_to_json(config)) == config
    ramp = dataclasses.replace(config, env=EnvConfig(collision_penalty=LinearRamp()))
    assert config_from_json(config_to_json(ramp)) == ramp
    with pytest.raises(ValueError, match=r"unknown .*Config fields"):
        config_from_json(config_to_json(config).replace('"seed"', '"sead"'))
    with pytest.raises(FileNotFoundError, match="known presets"):
        load_preset("no-such-preset")
    shutil.rmtree(Path("runs/never"), ignore_errors=True)


def test_command_line_assignments_are_typed_like_a_preset_and_refused_in_one_line():
    from clamgen.agents.encoders import EncoderConfig
    from clamgen.experiments.distill import DistillSettings

    changes = parse_assignments(
        DistillSettings,
        ["weight_decay=1", "seed=7", "stop_at_collision=true", "action_loss_kind=absolute"],
    )
    assert changes == {
        "weight_decay": 1.0,
        "seed": 7,
        "stop_at_collision": True,
        "action_loss_kind": "absolute",
    }
    assert type(changes["weight_decay"]) is float and type(changes["seed"]) is int
    assert DistillSettings(**changes).weight_decay == 1.0
    assert parse_assignments(EncoderConfig, ["strides=[2, 1, 1, 1]"]) == {"strides": (2, 1, 1, 1)}
    assert parse_assignments(DistillSettings, []) == {}
    refused = {
        "weight_decay": "is not FIELD=VALUE",
        "weight_decay=": "is not FIELD=VALUE",
        "sead=7": "'sead' is not a DistillSettings field; known: teacher",
        "weight_decay=x": "weight_decay = 'x': expected a number",
        "seed=7.5": "seed = 7.5: expected an integer",
        "stop_at_collision=yes": "expected true or false",
        "action_loss_kind=cubic": "expected one of 'squared', 'absolute'",
    }
    for item, message in refused.items():
        with pytest.raises(ValueError, match=message) as error:
            parse_assignments(DistillSettings, [item])
        assert "\n" not in str(error.value)


def test_collision_curriculum_ramps_like_the_paper():
    ramp = LinearRamp()
    assert ramp(0.0) == ramp(0.3) == 0.0
    assert ramp(0.6) == pytest.approx(0.05)
    assert ramp(0.9) == ramp(1.0) == pytest.approx(0.1)
    with pytest.raises(ValueError):
        LinearRamp(start_fraction=0.9, end_fraction=0.3)
