"""The RRT teacher (`loop.teacher_fraction`): which episodes it drives, what they store."""

import dataclasses

import pytest
from test_train import tiny_config

from clamgen.experiments.config import EnvConfig, LoopConfig
from clamgen.experiments.train import Trainer

pytest.importorskip("ompl")


def obstacle_config(run_dir, **loop):
    """A few blocked-path episodes, random actions whenever the teacher is not driving."""
    config = tiny_config(run_dir, total=160, learning_starts=400, **loop)
    return dataclasses.replace(config, env=EnvConfig(env_id="CLAMGen/ReachBlocked-v0", num_envs=2))


def test_teacher_probability_decreases_linearly_to_zero():
    loop = LoopConfig(teacher_fraction=0.6, teacher_until=0.5)
    assert loop.teacher_probability(0.0) == pytest.approx(0.6)
    assert loop.teacher_probability(0.25) == pytest.approx(0.3)
    assert loop.teacher_probability(0.5) == 0.0
    assert loop.teacher_probability(0.9) == 0.0
    assert LoopConfig().teacher_probability(0.0) == 0.0


@pytest.mark.parametrize(
    ("field", "value"),
    [("teacher_fraction", 1.5), ("teacher_fraction", float("nan")), ("teacher_until", 0.0)],
)
def test_bad_teacher_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f"loop.{field}"):
        LoopConfig(**{field: value})


def test_teacher_episodes_are_planned_stored_and_kept_out_of_the_agent_success_rate(tmp_path):
    trainer = Trainer(obstacle_config(tmp_path / "run", teacher_fraction=1.0))
    trainer.start_or_resume()
    assert all(t is not None for t in trainer.teachers)  # every first episode has a plan
    stored = []
    store = trainer.pipeline.store

    def spy(episode, obstacles=None):
        stored.append(episode)
        return store(episode, obstacles)

    trainer.pipeline.store = spy
    while trainer.progress.env_steps < 160:
        trainer.step()
    taught = trainer.progress.teacher_episodes
    assert 0 < taught <= trainer.progress.episodes == len(stored)
    assert len(trainer.recent_successes) == trainer.progress.episodes - taught
    # Blocked tasks: the obstacle-blind path collides, the planner's does not. The agent acts
    # at random here (before learning starts), so the clean successes are the planner's.
    clean = [e for e in stored if e.successes[-1] and not e.collisions.any()]
    assert len(clean) >= taught


def test_no_teacher_by_default(tmp_path):
    trainer = Trainer(obstacle_config(tmp_path / "run"))
    trainer.start_or_resume()
    assert trainer.teachers == [None, None]
    while trainer.progress.env_steps < 80:
        trainer.step()
    assert trainer.progress.teacher_episodes == 0
