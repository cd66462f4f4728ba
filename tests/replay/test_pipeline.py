"""The episode pipeline: a failed episode is relabelled exactly once, in one place, under every
combination of the HER flags of both stages; re-rendered episodes are stored when they return."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from clamgen.experiments.config import TrainConfig, load_preset
from clamgen.experiments.stage2 import Stage2Config, residual_stage
from clamgen.experiments.train import joint_stage
from clamgen.replay.pipeline import EpisodePipeline
from tests.replay.test_buffer import exact_reward, labelled_episode, make_buffer


class FakeRerender:
    """Records submissions; hands them back on poll/drain as a worker would."""

    def __init__(self) -> None:
        self.pending: list = []
        self.stats = {"rerender/pending": 0.0}
        self.closed = False

    def submit(self, episode, obstacles) -> None:
        self.pending.append((None, episode))

    def poll(self):
        done, self.pending = self.pending, []
        return done

    def drain(self, timeout=None):
        return self.poll()

    def close(self) -> None:
        self.closed = True


def pipeline_of(stage) -> EpisodePipeline:
    rerender = FakeRerender() if stage.make_rerender is not None else None
    return EpisodePipeline(make_buffer(200), stage.hindsight, exact_reward, rerender=rerender)


# (failed episode: 6 steps, collides at step 4) -> original 6 + forward 4 + reversed 4 steps.
FAILED_STEPS, RELABELLED_STEPS = 6, 6 + 4 + 4


@pytest.mark.parametrize("reversible", [False, True])
def test_stage1_relabels_once(reversible):
    config = dataclasses.replace(
        TrainConfig(), replay=dataclasses.replace(TrainConfig().replay, reversible_her=reversible)
    )
    pipeline = pipeline_of(joint_stage(config))
    pipeline.store(labelled_episode(0, FAILED_STEPS, collide_at=4))
    expected = (3, RELABELLED_STEPS) if reversible else (1, FAILED_STEPS)
    assert (pipeline.buffer.num_episodes, len(pipeline.buffer)) == expected


@pytest.mark.parametrize(
    ("image_her", "reversible_her"), list(itertools.product([False, True], [False, True]))
)
def test_stage2_with_obstacle_poses_relabels_once_whichever_flag_asks(image_her, reversible_her):
    config = load_preset("residual-obstacles", Stage2Config)
    config = dataclasses.replace(
        config,
        image_her=image_her,
        replay=dataclasses.replace(config.replay, reversible_her=reversible_her),
    )
    stage = residual_stage(config)
    assert stage.make_rerender is None  # poses show no goal: nothing to re-render
    pipeline = pipeline_of(stage)
    pipeline.store(labelled_episode(0, FAILED_STEPS, collide_at=4))
    relabelled = image_her or reversible_her
    expected = (3, RELABELLED_STEPS) if relabelled else (1, FAILED_STEPS)
    assert (pipeline.buffer.num_episodes, len(pipeline.buffer)) == expected


@pytest.mark.parametrize("image_her", [False, True])
def test_stage2_with_images_rerenders_the_relabelled_episodes_before_storing_them(image_her):
    config = dataclasses.replace(load_preset("residual-cpu", Stage2Config), image_her=image_her)
    stage = residual_stage(config)
    assert (stage.make_rerender is not None) == image_her
    pipeline = pipeline_of(stage)
    assert pipeline.store(labelled_episode(0, FAILED_STEPS, collide_at=4)) == 1
    assert pipeline.buffer.num_episodes == 1  # the relabelled ones are still being rendered
    stored_later = pipeline.flush()
    assert stored_later == (2 if image_her else 0)
    expected = (3, RELABELLED_STEPS) if image_her else (1, FAILED_STEPS)
    assert (pipeline.buffer.num_episodes, len(pipeline.buffer)) == expected
    assert pipeline.collect() == 0  # nothing is stored twice
    with pytest.raises(ValueError, match="her_ratio=0"):  # no sample-time HER on images
        dataclasses.replace(config, replay=dataclasses.replace(config.replay, her_ratio=0.5))


def test_a_successful_episode_is_stored_alone():
    config = load_preset("residual-obstacles", Stage2Config)
    pipeline = pipeline_of(residual_stage(config))
    episode = labelled_episode(0, 3)
    episode = dataclasses.replace(episode, successes=np.array([False, False, True]))
    pipeline.store(episode)
    assert pipeline.buffer.num_episodes == 1
