"""`env.training_collision_margin_m`: a clearance the training envs keep, never evaluation."""

import dataclasses

import numpy as np
import pytest
from test_train import tiny_config

from clamgen.envs.reach_env import COLLISION_CHECK_RESOLUTION_RAD
from clamgen.experiments.config import EnvConfig
from clamgen.experiments.train import Trainer, make_env
from clamgen.tasks.blocked import blind_goal_joints


@pytest.mark.parametrize("value", [-0.01, 0.5, float("nan"), "2cm"])
def test_bad_margins_are_refused_naming_the_field(value):
    with pytest.raises(ValueError, match=r"env\.training_collision_margin_m"):
        EnvConfig(training_collision_margin_m=value)


def test_only_training_envs_get_the_margin(tmp_path):
    env = EnvConfig(env_id="CLAMGen/ReachBlocked-v0", num_envs=2, training_collision_margin_m=0.03)
    trainer = Trainer(dataclasses.replace(tiny_config(tmp_path / "run", total=40), env=env))
    assert [e.scene.collision_margin_m for e in trainer.envs] == [0.03, 0.03]
    assert trainer.eval_env.scene.collision_margin_m == 0.0
    assert make_env(env).scene.collision_margin_m == 0.0


def test_the_margin_stops_the_arm_short_of_the_obstacle():
    """On blocked tasks the blind straight joint path hits an obstacle: with the margin, the
    training env's checker stops the arm no later, and on some task strictly earlier."""
    config = EnvConfig(env_id="CLAMGen/ReachBlocked-v0", training_collision_margin_m=0.05)
    clear, training = make_env(config), make_env(config, training=True)
    earlier = 0
    for seed in range(5):
        clear.reset(seed=seed)
        task = clear.unwrapped.task
        training.reset(options={"task": task})
        goal = blind_goal_joints(task.start_joints, task.target_position_m)
        reached = []
        for env in (clear, training):
            joints, collided = env.unwrapped.scene.move_along(
                task.start_joints, goal, COLLISION_CHECK_RESOLUTION_RAD
            )
            assert collided
            reached.append(np.abs(joints - task.start_joints).max())
        assert reached[1] <= reached[0]
        earlier += reached[1] < reached[0]
    assert earlier > 0
