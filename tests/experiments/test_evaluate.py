import json

import pytest

from clamgen.experiments.evaluate import EpisodeRecord, per_task


def test_per_task_keeps_each_episode_in_order_and_the_median_act():
    records = [
        EpisodeRecord(
            seed=3,
            reached=True,
            collided=False,
            steps=20,
            tip_path_m=0.3,
            act_times_s=[0.001, 0.003],
        ),
        EpisodeRecord(
            seed=4, reached=True, collided=True, steps=31, tip_path_m=0.5, act_times_s=[0.002]
        ),
        EpisodeRecord(
            seed=5, reached=False, collided=False, steps=80, tip_path_m=0.1, act_times_s=[0.004]
        ),
    ]
    out = per_task(records)
    # A reach after a collision is no success (the spec's criterion).
    assert out["success"] == [True, False, False]
    assert out["collided"] == [False, True, False]
    assert out["steps"] == [20, 31, 80]
    assert out["act_median_ms"] == pytest.approx(2.5)
    json.dumps(out)  # plain Python types, for the result files
