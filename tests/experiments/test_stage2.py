"""Stage 2 end to end on tiny budgets: privileged poses and images with re-rendered HER."""

import dataclasses
import json

import numpy as np
import pytest

from clamgen.agents.aux_losses import AuxLossConfig
from clamgen.agents.encoders import EncoderConfig
from clamgen.agents.residual import ResidualConfig
from clamgen.experiments.config import EnvConfig, LoopConfig, load_preset
from clamgen.experiments.stage2 import (
    Stage2Config,
    Stage2Trainer,
    load_residual_agent,
    residual_stage,
)
from clamgen.experiments.train import POLICY_NAME
from clamgen.replay import ReplayConfig
from clamgen.schedules import LinearRamp

LOOP = LoopConfig(
    total_env_steps=240,
    learning_starts=40,
    updates_per_step=0.25,
    eval_every_steps=0,
    num_eval_episodes=2,
    checkpoint_every_steps=0,
    log_every_steps=40,
    seed=2,
)


def privileged_config(run_dir, base_policy) -> Stage2Config:
    """The privileged preset, shrunk to a test's size."""
    preset = load_preset("residual-obstacles", Stage2Config)
    return dataclasses.replace(
        preset,
        run_dir=run_dir,
        base_policy=base_policy,
        env=dataclasses.replace(preset.env, num_envs=2),
        agent=dataclasses.replace(preset.agent, batch_size=16, hidden_sizes=(32,)),
        replay=ReplayConfig(capacity=5_000),
        loop=LOOP,
    )


def test_privileged_residual_trains_exports_and_loads(tmp_path, base_policy):
    config = privileged_config(tmp_path / "run", base_policy)
    summary = Stage2Trainer(config).run(show_progress=False)
    assert 0 <= summary["eval/success_rate"] <= 1
    agent, loaded = load_residual_agent(config.run_dir / POLICY_NAME)
    assert loaded == config
    obs = {
        "observation": np.zeros(6, np.float32),
        "desired_goal": np.full(3, 0.4, np.float32),
        "obstacles": np.zeros((2, 8), np.float32),
    }
    assert agent.act(obs, deterministic=True).shape == (6,)
    # `clamgen eval --table 2` runs it with the observations it was trained on.
    from clamgen.cli import EvalConfig, evaluate_table

    rows = evaluate_table(
        EvalConfig(
            table=2,
            policy=str(config.run_dir / POLICY_NAME),
            num_tasks=2,
            out=tmp_path / "row",
            name="privileged",
        )
    )
    assert [row.family for row in rows] == ["obstacles", "blocked"]  # both task families
    for row in rows:
        assert row.name == "privileged" and 0 <= row.success_rate <= 1 and row.median_step_ms > 0


def image_config(tmp_path, base_policy, **kwargs) -> Stage2Config:
    encoder = EncoderConfig(
        image_size=24,
        num_views=2,
        num_channels=8,
        strides=(2, 2, 1, 1),
        hidden_dim=32,
        feature_dim=16,
        low_dim_size=16,
    )
    return Stage2Config(
        run_dir=tmp_path / "run",
        base_policy=base_policy,
        rerender_in_process=True,
        env=EnvConfig(
            env_id="CLAMGen/ReachObstacles-v0",
            num_envs=2,
            num_views=2,
            image_size=28,
            obs_mode="both",
            collision_penalty=LinearRamp(),
        ),
        agent=ResidualConfig(
            encoder=encoder,
            crop_padding=2,
            batch_size=16,
            hidden_sizes=(32,),
            aux=AuxLossConfig(collision_hidden_sizes=(16,)),
            warmup_updates=5,
        ),
        replay=ReplayConfig(capacity=5_000, her_ratio=0.0, reversible_her=False),
        loop=LOOP,
        **kwargs,
    )


def test_image_residual_with_rerendered_her_trains_and_resumes(tmp_path, base_policy):
    config = image_config(tmp_path, base_policy)
    trainer = Stage2Trainer(config)
    summary = trainer.run(show_progress=False)
    assert 0 <= summary["eval/success_rate"] <= 1
    # Failed episodes were relabelled and re-rendered: more episodes stored than played.
    assert trainer.buffer.num_episodes > trainer.progress.episodes
    metrics = (config.run_dir / "metrics.csv").read_text()
    assert "rerender/frames_per_s" in metrics and "train/curl_loss" in metrics
    longer = dataclasses.replace(config, loop=dataclasses.replace(LOOP, total_env_steps=280))
    resumed = Stage2Trainer(longer)
    assert resumed.start_or_resume() and resumed.progress.env_steps == 240
    agent, _ = load_residual_agent(config.run_dir / POLICY_NAME)
    assert agent.config.encoder.image_size == 24


def test_image_residual_trains_on_noisy_depth(tmp_path, base_policy):
    """`env.depth_noise_m`: the training and validation envs and image HER's re-rendering all
    see the camera's noise; without views it is refused."""
    config = image_config(tmp_path, base_policy)
    noisy = dataclasses.replace(config, env=dataclasses.replace(config.env, depth_noise_m=0.01))
    trainer = Stage2Trainer(noisy)
    assert {env.depth_noise_m for env in (*trainer.envs, trainer.eval_env)} == {0.01}
    assert trainer.pipeline.rerender.depth_noise_m == 0.01
    trainer.run(show_progress=False)
    assert trainer.buffer.num_episodes > trainer.progress.episodes  # re-rendered, noisy
    with pytest.raises(ValueError, match="depth_noise_m"):
        dataclasses.replace(config.env, num_views=0, obs_mode="joints", depth_noise_m=0.01)
    with pytest.raises(ValueError, match="depth_noise_m"):
        dataclasses.replace(config.env, depth_noise_m=-0.01)


def test_stage2_config_refuses_inconsistent_settings(tmp_path, base_policy):
    config = image_config(tmp_path, base_policy)
    with pytest.raises(ValueError, match="num_views"):
        dataclasses.replace(config, env=dataclasses.replace(config.env, num_views=3))
    with pytest.raises(ValueError, match="crop plus padding"):
        dataclasses.replace(config, env=dataclasses.replace(config.env, image_size=32))
    with pytest.raises(ValueError, match="sample-time HER"):
        dataclasses.replace(config, replay=ReplayConfig(her_ratio=0.8))


def test_shipped_vision_policy_runs_out_of_the_box(tmp_path):
    from clamgen.cli import EvalConfig, evaluate_table

    rows = evaluate_table(
        EvalConfig(table=2, policy="residual-2views", num_tasks=2, out=tmp_path / "row")
    )
    assert [row.family for row in rows] == ["obstacles", "blocked"]
    assert all(0 <= row.success_rate <= 1 and row.median_act_ms > 0 for row in rows)


def test_shipped_image_only_policy_acts_from_images_alone():
    from clamgen.experiments.policies import load_policy, policy_observation

    policy, _, env_kwargs = load_policy("image-only")
    assert policy_observation(policy) == "images" and env_kwargs["num_views"] == 2


def test_image_only_policy_evaluates_as_the_image_rows_of_table1(tmp_path, base_policy):
    config = image_config(tmp_path, base_policy)
    config = dataclasses.replace(
        config,
        env=dataclasses.replace(config.env, env_id="CLAMGen/Reach-v0"),
        agent=dataclasses.replace(config.agent, residual=False, use_low_dim=False),
        loop=dataclasses.replace(LOOP, total_env_steps=80),
    )
    Stage2Trainer(config).run(show_progress=False)
    from clamgen.cli import EvalConfig, evaluate_table

    out = tmp_path / "table1"
    rows = evaluate_table(
        EvalConfig(
            table=1, policy=str(config.run_dir / POLICY_NAME), num_tasks=2, speeds=("0.1",), out=out
        )
    )
    assert len(rows) == 1 and 0 <= rows[0].success_rate <= 1 and rows[0].median_act_ms > 0
    assert '"observation": "images"' in out.with_suffix(".json").read_text()
    assert "| 1.160 |" in out.with_suffix(".md").read_text()  # the paper's image row, 10 cm/s


def test_encoder_pretraining_reads_the_state_and_hands_the_encoder_to_rl(tmp_path, base_policy):
    from clamgen.experiments.stage2 import EncoderPretrainConfig

    config = image_config(tmp_path, base_policy)
    pretrain = EncoderPretrainConfig(scenes=200, held_out_scenes=50, steps=150, lr=3e-3)
    config = dataclasses.replace(
        config,
        env=dataclasses.replace(config.env, env_id="CLAMGen/Reach-v0"),
        agent=dataclasses.replace(
            config.agent, residual=False, use_low_dim=False, privileged_critic=True
        ),
        loop=dataclasses.replace(LOOP, total_env_steps=40),
        pretrain=pretrain,
    )
    trainer = Stage2Trainer(config)
    before = [p.detach().clone() for p in trainer.agent.critic.encoder.parameters()]
    trainer.start_or_resume()
    summary = json.loads((config.run_dir / "pretrain.json").read_text())
    assert summary["after/joint_error_rad"] < 0.8 * summary["before/joint_error_rad"]
    agent = trainer.agent
    encoder = agent.critic.encoder.state_dict()
    assert any(not np.array_equal(a, b) for a, b in zip(before, encoder.values(), strict=True))
    for copy in (agent.critic_target.encoder, agent.key_encoder):
        for key, value in copy.state_dict().items():
            np.testing.assert_array_equal(value, encoder[key])
    trainer.run(show_progress=False)
    with pytest.raises(ValueError, match="pretrain"):
        dataclasses.replace(
            config,
            agent=dataclasses.replace(
                image_config(tmp_path, base_policy).agent, obs_source="obstacles"
            ),
            env=dataclasses.replace(config.env, include_obstacle_state=True),
        )


@pytest.mark.parametrize(
    ("name", "views"), [("residual-3views", 3), ("residual-2views", 2), ("residual-1view", 1)]
)
def test_shipped_vision_policies_load_by_name_and_act_from_their_views(name, views):
    from clamgen.envs import ReachEnv
    from clamgen.experiments.policies import load_policy

    policy, source, env_kwargs = load_policy(name)
    assert env_kwargs["num_views"] == views and name in source
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
    obs, _ = env.reset(seed=2_000_000_123)
    action = policy.act(obs)
    env.close()
    assert action.shape == (6,) and np.all(np.abs(action) <= 1)


def test_zoomed_views_count_twice_in_the_encoder(tmp_path, base_policy):
    config = image_config(tmp_path, base_policy)
    env = dataclasses.replace(config.env, zoom_views=True)
    with pytest.raises(ValueError, match="x 2 with env"):
        dataclasses.replace(config, env=env)
    encoder = dataclasses.replace(config.agent.encoder, num_views=4)
    agent = dataclasses.replace(config.agent, encoder=encoder)
    zoomed = dataclasses.replace(config, env=env, agent=agent)  # 2 views + 2 zoomed
    assert zoomed.agent.encoder.num_views == 4
    with pytest.raises(ValueError, match="image_her re-renders the views only"):
        residual_stage(zoomed).make_rerender()


def test_init_policy_starts_a_run_from_another_runs_policy(tmp_path, base_policy):
    config = privileged_config(tmp_path / "source", base_policy)
    Stage2Trainer(config).run(show_progress=False)
    source, _ = load_residual_agent(config.run_dir / POLICY_NAME)
    started_config = dataclasses.replace(
        config,
        run_dir=tmp_path / "finetune",
        init_policy=str(config.run_dir / POLICY_NAME),
        agent=dataclasses.replace(config.agent, warmup_updates=0, freeze_encoder=True),
    )
    started = Stage2Trainer(started_config).agent
    rng = np.random.default_rng(0)
    obs = {
        "observation": rng.uniform(-1, 1, (4, 6)).astype(np.float32),
        "achieved_goal": np.full((4, 3), 0.3, np.float32),
        "desired_goal": rng.uniform(0.2, 0.5, (4, 3)).astype(np.float32),
        "obstacles": rng.uniform(-0.3, 0.3, (4, 2, 8)).astype(np.float32),
    }
    np.testing.assert_array_equal(started.act(obs, True), source.act(obs, True))
    with pytest.raises(ValueError, match="warmup_updates=0"):
        dataclasses.replace(started_config, agent=config.agent)
    wider = dataclasses.replace(
        started_config, agent=dataclasses.replace(started_config.agent, hidden_sizes=(64,))
    )
    with pytest.raises(ValueError, match="does not fit this run's agent config") as error:
        Stage2Trainer(wider)
    assert "\n" not in str(error.value)
