"""The action-chunk test's targets and temporal ensembling (results/stage2/distill/chunks.py)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def chunks(results_script):
    return results_script("stage2/distill/chunks.py")


def test_future_labels_follow_each_episode_and_hold_its_last(chunks):
    labels = np.arange(7, dtype=np.float32)[:, None] * np.ones((1, 2), np.float32)
    episode = np.array([0, 1, 0, 1, 0, 0, 1])  # two interleaved episodes, rows in step order
    future = chunks.future_labels(labels, episode, 2)[:, :, 0]
    np.testing.assert_array_equal(future, [[2, 4], [3, 6], [4, 5], [6, 6], [5, 5], [5, 5], [6, 6]])


def test_default_distiller_adds_no_extra_loss():
    from clamgen.experiments.distill import Distiller

    assert Distiller.extra_loss(None, np.zeros(2, int), {}, None) is None
