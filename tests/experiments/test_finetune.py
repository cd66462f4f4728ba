"""results/stage2/finetune/finetune.py: a distilled student's own config with the fine-tuning
settings, starting from the student."""

import argparse
import dataclasses

import numpy as np

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.stage2 import Stage2Trainer, load_residual_agent


def test_finetune_config_keeps_the_students_networks_and_starts_from_it(tmp_path, results_script):
    finetune = results_script("stage2/finetune/finetune.py")
    student = ckpt.resolve_policy_path("residual-1view")
    args = argparse.Namespace(
        steps=40,
        anchor=10.0,
        critic_first=5,
        actor_lr=1e-4,
        penalty=finetune.COLLISION_PENALTY,
        collision_ends=True,
        n_step=3,
        train_encoder=False,
        learning_starts=10,
        eval_every=20,
        eval_episodes=1,
        seed=0,
    )
    config = finetune.finetune_config(student, tmp_path / "run", args)
    _, own = load_residual_agent(student)
    assert config.agent.encoder == own.agent.encoder
    assert config.agent.hidden_sizes == own.agent.hidden_sizes
    assert config.env.num_views == own.env.num_views and config.env.env_id == own.env.env_id
    assert config.agent.freeze_encoder and config.agent.warmup_updates == 0
    assert config.agent.anchor_weight == 10.0 and config.agent.critic_first_updates == 5
    assert config.env.collision_ends_episode and config.replay.n_step == 3
    assert config.env.collision_penalty(0.0) == config.env.collision_penalty(1.0) == 1.0
    assert not config.image_her and config.init_policy == str(student)
    # The run's agent starts as the student acts.
    source, _ = load_residual_agent(student)
    trainer = Stage2Trainer(config)
    obs, _ = trainer.eval_env.reset(seed=3)
    np.testing.assert_array_equal(trainer.agent.act(obs, True), source.act(obs, True))
    # A shipped policy by name starts the same networks.
    named = dataclasses.replace(config, init_policy="residual-1view", run_dir=tmp_path / "named")
    np.testing.assert_array_equal(Stage2Trainer(named).agent.act(obs, True), source.act(obs, True))
