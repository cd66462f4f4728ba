"""Aggregation over training seeds (rliable) on small score arrays worked out by hand."""

import json

import numpy as np
import pytest

from clamgen.experiments import aggregate as A

REPS = 300  # enough for the properties below, cheap on a shared machine

# Eight runs on one condition: the IQM drops the lowest two and the highest two (25% each
# side) and averages 0.2, 0.3, 0.4, 0.5; the mean is 3.1 / 8.
EIGHT = A.score_matrix([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 1.0])


def test_mean_and_iqm_of_a_known_array():
    row = A.aggregate_rows({"a": EIGHT}, reps=REPS)["a"]
    assert row.num_runs == 8 and row.num_conditions == 1
    assert row.iqm.value == pytest.approx(0.35)
    assert row.mean.value == pytest.approx(0.3875)


def test_iqm_pools_runs_and_conditions():
    # 4 runs x 2 conditions = 8 scores; trimming 2 from each end leaves 0.3, 0.4, 0.5, 0.6.
    scores = A.score_matrix([[0.1, 0.5], [0.3, 0.9], [0.4, 0.6], [0.2, 0.8]])
    row = A.aggregate_rows({"a": scores}, reps=REPS)["a"]
    assert row.iqm.value == pytest.approx(0.45)
    assert row.mean.value == pytest.approx(3.8 / 8)


def test_intervals_contain_the_estimate_and_lie_within_the_scores():
    rows = A.aggregate_rows(
        {"a": EIGHT, "b": A.score_matrix([[0.9, 0.8], [0.95, 0.7], [1.0, 1.0]])}, reps=REPS
    )
    for row in rows.values():
        for estimate in (row.mean, row.iqm):
            assert estimate.low <= estimate.value <= estimate.high
            assert estimate.high > estimate.low  # the runs differ, so the interval has width
    assert 0.0 <= rows["a"].mean.low and rows["a"].mean.high <= 1.0


def test_identical_runs_give_a_zero_width_interval():
    rows = A.aggregate_rows(
        {"a": A.score_matrix([0.7, 0.7, 0.7]), "one": A.score_matrix([[0.4, 0.6]])}, reps=REPS
    )
    assert (rows["a"].mean.low, rows["a"].mean.value, rows["a"].mean.high) == pytest.approx(
        (0.7, 0.7, 0.7)
    )
    # One run resamples to itself: its interval is its point.
    assert (rows["one"].iqm.low, rows["one"].iqm.high) == pytest.approx((0.5, 0.5))
    profile = A.performance_profiles({"one": A.score_matrix([0.3])}, np.array([0.2, 0.5]))["one"]
    assert profile.fraction.tolist() == profile.low.tolist() == profile.high.tolist() == [1, 0]


def test_probability_of_improvement_separated_identical_and_partial():
    high = A.score_matrix([[0.9, 0.8], [0.95, 0.85], [1.0, 0.9]])
    low = A.score_matrix([[0.1, 0.2], [0.3, 0.1]])
    # x = 0.5, 0.7, 0.9 vs y = 0.6, 0.65: 0.7 and 0.9 beat both, 0.5 neither -> 4 / 6.
    x, y = A.score_matrix([0.5, 0.7, 0.9]), A.score_matrix([0.6, 0.65])
    # A tie counts one half: x = 0.5, 0.7 vs y = 0.5 -> (0.5 + 1) / 2.
    tie_x, tie_y = A.score_matrix([0.5, 0.7]), A.score_matrix([0.5])
    scores = {"high": high, "low": low, "x": x, "y": y, "tx": tie_x, "ty": tie_y}
    pairs = [("high", "low"), ("low", "high"), ("high", "high"), ("x", "y"), ("tx", "ty")]
    poi = A.probability_of_improvement(scores, pairs, reps=REPS)
    assert poi[("high", "low")].value == 1.0
    assert (poi[("high", "low")].low, poi[("high", "low")].high) == (1.0, 1.0)
    assert poi[("low", "high")].value == 0.0
    assert poi[("high", "high")].value == 0.5
    assert poi[("x", "y")].value == pytest.approx(4 / 6)
    assert poi[("tx", "ty")].value == pytest.approx(0.75)
    for estimate in poi.values():
        assert estimate.contains(estimate.value)


def test_probability_of_improvement_needs_the_same_conditions():
    scores = {"a": A.score_matrix([[0.1, 0.2]]), "b": A.score_matrix([0.3])}
    with pytest.raises(ValueError, match="same conditions"):
        A.probability_of_improvement(scores, [("a", "b")], reps=REPS)


def test_seeded_reproducibility_and_the_global_generator_left_alone():
    scores = {"a": EIGHT}
    np.random.seed(123)  # noqa: NPY002
    before = np.random.get_state()[1].copy()  # noqa: NPY002
    first = A.aggregate_rows(scores, reps=REPS, seed=7)["a"]
    after = np.random.get_state()[1]  # noqa: NPY002
    assert np.array_equal(before, after)
    assert A.aggregate_rows(scores, reps=REPS, seed=7)["a"] == first
    others = {A.aggregate_rows(scores, reps=REPS, seed=s)["a"].iqm for s in range(8, 12)}
    assert len(others | {first.iqm}) > 1  # the seed does drive the bootstrap


def test_performance_profile_counts_scores_above_each_threshold():
    scores = A.score_matrix([0.2, 0.6, 0.9])
    taus = np.array([0.0, 0.5, 0.6, 0.95])
    profile = A.performance_profiles({"a": scores}, taus, reps=REPS)["a"]
    # Scores strictly above tau: 3, 2 (0.6 is not above 0.6, so 1), 0.
    assert profile.fraction == pytest.approx([1.0, 2 / 3, 1 / 3, 0.0])
    assert np.all(profile.low <= profile.fraction) and np.all(profile.fraction <= profile.high)


def test_sample_efficiency_curves_on_common_steps():
    curves = {
        "row": [
            ([1000, 2000, 3000], [0.0, 0.4, 0.8]),
            ([1000, 2000], [0.2, 0.6]),  # stopped early: the curve ends at 2000
            ([1000, 2000, 3000], [0.1, 0.5, 0.9]),
        ]
    }
    curve = A.sample_efficiency_curves(curves, reps=REPS)["row"]
    assert curve.steps.tolist() == [1000, 2000]
    assert curve.num_runs == 3
    assert curve.mean == pytest.approx([0.1, 0.5])
    # The IQM trims int(0.25 * 3) = 0 values from each end: with three runs it is the mean.
    assert curve.iqm == pytest.approx([0.1, 0.5])
    assert np.all(curve.mean_low <= curve.mean) and np.all(curve.mean <= curve.mean_high)
    assert np.all(curve.mean_low >= 0.0) and np.all(curve.mean_high <= 0.6)


def test_score_matrix_refuses_ragged_or_empty_scores():
    with pytest.raises(ValueError):
        A.score_matrix([[0.1, 0.2], [0.3]])
    with pytest.raises(ValueError, match="score matrix"):
        A.score_matrix([])
    with pytest.raises(ValueError, match="finite"):
        A.score_matrix([0.1, float("nan")])


def test_vectorised_aggregates_equal_rliables_own():
    from rliable import library as rly
    from rliable import metrics

    scores = np.random.default_rng(0).uniform(size=(5, 2, 7))
    per_step = A._per_step_mean_and_iqm(scores)
    assert per_step[:7] == pytest.approx([metrics.aggregate_mean(scores[..., t]) for t in range(7)])
    assert per_step[7:] == pytest.approx([metrics.aggregate_iqm(scores[..., t]) for t in range(7)])
    taus = np.linspace(0, 1, 11)
    assert A._score_distribution(scores[..., 0], taus) == pytest.approx(
        rly.score_distributions(scores[..., 0], taus)
    )


def test_seed_lines_give_each_seed_and_the_mean_with_an_interval_from_two_seeds():
    runs = [{"blocked": (0.8, 0.02)}, {"blocked": (0.9, 0.04)}]
    (one,) = A.seed_lines(runs[:1], ["blocked"])
    assert one == (
        "  blocked   success mean 0.800, per seed 0.800; collision mean 0.020, per seed 0.020"
    )
    (two,) = A.seed_lines(runs, ["blocked"])
    assert two == (
        "  blocked   success mean 0.850 (0.800-0.900), per seed 0.800, 0.900; "
        "collision mean 0.030 (0.020-0.040), per seed 0.020, 0.040"
    )


def test_row_scores_read_success_and_collision_per_family_from_an_eval_row(tmp_path):
    path = tmp_path / "row.json"
    rows = [
        {"family": "obstacles", "success_rate": 0.95, "collision_rate": 0.025, "num_tasks": 200},
        {"family": "blocked", "success_rate": 0.85, "collision_rate": 0.06, "num_tasks": 200},
    ]
    path.write_text(json.dumps({"policy": "p", "rows": rows}))
    assert A.row_scores(path) == {"obstacles": (0.95, 0.025), "blocked": (0.85, 0.06)}
