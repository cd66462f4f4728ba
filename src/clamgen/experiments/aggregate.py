"""Aggregate success over training seeds with rliable (Agarwal et al., "Deep RL at the Edge of
the Statistical Precipice", NeurIPS 2021): the library does the statistics, this module only
shapes our results into its score matrices.

A *run* is one training run (preset x overrides x training seed). Its *scores* are success
rates on the test tasks, one per evaluation condition: the target speeds of Table 1, or the task
families of Table 2 (`obstacles`, `blocked`). A row's scores form the matrix rliable expects,
`(num_runs, num_conditions)`, and the stratified bootstrap resamples runs within each condition.
Sample-efficiency curves use the validation success that training logs (`eval/success_rate` in
each run's `metrics.csv`, on validation seeds) as a `(num_runs, 1, num_steps)` array.

Every estimate takes a `seed`: rliable's bootstrap draws from NumPy's global generator, so each
call seeds it for its own duration and restores the caller's state afterwards.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.stats
from rliable import library as rly
from rliable import metrics

CONFIDENCE = 0.95
"""Coverage of every interval (two-sided)."""
DEFAULT_REPS = 2_000
"""Bootstrap replications per estimate (rliable's own default for profiles); with 3-5 runs per
row the interval's ends move by about a point between seeds of the bootstrap."""
POI_REPS = 1_000
"""Replications for the probability of improvement: each one runs a Mann-Whitney U test per
condition, about 100 times the cost of a mean."""
DEFAULT_SEED = 0
PROFILE_TAUS = np.linspace(0.0, 1.0, 101)
"""Success thresholds of the performance profiles."""
SEED_SET_KIND = "clamgen-seeds"
"""The `kind` of a seed set's JSON (`write_seed_set`), which `clamgen report` aggregates."""


@contextlib.contextmanager
def seeded_numpy(seed: int) -> Iterator[None]:
    """Seed NumPy's global generator (which rliable's bootstrap uses) inside the block, and
    restore the caller's state afterwards."""
    # The legacy global API on purpose: it is what rliable draws from.
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


@dataclass(frozen=True)
class Estimate:
    """A point estimate and its 95% stratified-bootstrap interval."""

    value: float
    low: float
    high: float

    def contains(self, x: float) -> bool:
        return self.low - 1e-12 <= x <= self.high + 1e-12

    def as_dict(self) -> dict[str, float]:
        return {"value": self.value, "low": self.low, "high": self.high}


@dataclass(frozen=True)
class RowAggregate:
    """Mean and IQM success of one row over its runs and conditions."""

    num_runs: int
    num_conditions: int
    mean: Estimate
    iqm: Estimate


def score_matrix(run_scores: Sequence[Sequence[float]]) -> np.ndarray:
    """Runs' scores (one list per run, one value per condition, same order) as rliable's
    `(num_runs, num_conditions)` float array; a ValueError for ragged or empty input."""
    matrix = np.asarray(run_scores, dtype=float)
    if matrix.ndim == 1:
        matrix = matrix[:, None]
    if matrix.ndim != 2 or matrix.size == 0:
        raise ValueError(f"need a (runs, conditions) score matrix, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError("scores must be finite")
    return matrix


def _interval_estimates(
    scores: Mapping[str, np.ndarray], func, reps: int, seed: int
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """`rliable.library.get_interval_estimates` for rows with several runs; a row with one run
    resamples to itself every time, so its interval is its point (and costs no bootstrap)."""
    several = {k: v for k, v in scores.items() if v.shape[0] > 1}
    points, intervals = {}, {}
    if several:
        with seeded_numpy(seed):
            points, intervals = rly.get_interval_estimates(
                several, func, reps=reps, confidence_interval_size=CONFIDENCE
            )
    for name, matrix in scores.items():
        if name not in several:
            points[name] = np.asarray(func(matrix), dtype=float)
            intervals[name] = np.stack([points[name], points[name]])
    return points, intervals


def _mean_and_iqm(scores: np.ndarray) -> np.ndarray:
    return np.array([metrics.aggregate_mean(scores), metrics.aggregate_iqm(scores)])


def aggregate_rows(
    scores: Mapping[str, np.ndarray], reps: int = DEFAULT_REPS, seed: int = DEFAULT_SEED
) -> dict[str, RowAggregate]:
    """Mean and IQM (25% trimmed mean over runs x conditions) of each row's score matrix, with
    95% stratified-bootstrap percentile intervals (`rliable.library.get_interval_estimates`)."""
    points, intervals = _interval_estimates(scores, _mean_and_iqm, reps, seed)
    out = {}
    for name, matrix in scores.items():
        point, (low, high) = points[name], intervals[name]
        out[name] = RowAggregate(
            num_runs=matrix.shape[0],
            num_conditions=matrix.shape[1],
            mean=Estimate(float(point[0]), float(low[0]), float(high[0])),
            iqm=Estimate(float(point[1]), float(low[1]), float(high[1])),
        )
    return out


def seed_mean(name: str, values: Sequence[float]) -> str:
    """'<name> mean M (low-high), per seed a, b, ...' for one measure of a row evaluated on
    several training seeds: the mean over seeds with its 95% stratified-bootstrap interval
    (`aggregate_rows`; from two seeds, none for one) and each seed's value."""
    column = np.asarray(values, dtype=float)[:, None]
    interval = ""
    if len(column) > 1:
        mean = aggregate_rows({name: column})[name].mean
        interval = f" ({mean.low:.3f}-{mean.high:.3f})"
    per_seed = ", ".join(f"{v:.3f}" for v in column[:, 0])
    return f"{name} mean {column.mean():.3f}{interval}, per seed {per_seed}"


def row_scores(path: str | Path) -> dict[str, tuple[float, float]]:
    """{family: (success rate, collision rate)} of one `clamgen eval --table 2` row's JSON: the
    per-seed input of `seed_lines`."""
    rows = json.loads(Path(path).read_text())["rows"]
    return {r["family"]: (r["success_rate"], r["collision_rate"]) for r in rows}


def seed_lines(runs: Sequence[Mapping[str, tuple[float, float]]], families: Sequence[str]):
    """One line per task family for a row evaluated on several training seeds, from each
    seed's {family: (success rate, collision rate)}: `seed_mean` of the success and of the
    collision rate."""
    return [
        f"  {family:9s} "
        + "; ".join(
            seed_mean(what, [run[family][index] for run in runs])
            for index, what in enumerate(("success", "collision"))
        )
        for family in families
    ]


def table2_row_name(path: str | Path) -> str:
    """The one row name of a `clamgen eval --table 2` JSON (its rows are the task families)."""
    names = {row["name"] for row in json.loads(Path(path).read_text())["rows"]}
    if len(names) != 1:
        raise ValueError(f"{path}: expected one row name, found {sorted(names)}")
    return names.pop()


def seed_summary(rows: Mapping[str, Sequence[tuple[int, Path]]], families: Sequence[str]) -> str:
    """Text for rows evaluated on several training seeds, {row: [(seed, Table 2 JSON), ...]}:
    per row a line with its seeds, then `seed_lines`."""
    lines = []
    for row, runs in rows.items():
        lines.append(f"{row}; {len(runs)} seeds {[seed for seed, _ in runs]}")
        lines += seed_lines([row_scores(path) for _, path in runs], families)
    return "\n".join(lines)


def write_seed_set(
    rows: Mapping[str, Sequence[tuple[int, Path]]],
    out: Path,
    command: str,
    note: str,
    compare: Sequence[tuple[str, str]] = (),
    compare_wrappers: Sequence[tuple[str, str]] = (),
) -> Path:
    """Write `out`, a seed set: for each row (a name of our choosing) its runs, each a training
    seed and the `clamgen eval --table 2` JSON holding its test scores (named relative to `out`'s
    folder, with that file's own row name). `command` writes it again; `note` says what the
    seeds vary; `compare` names (X, Y) pairs of its rows, X a policy through a test-time wrapper
    and Y the same policies alone, whose probability of improvement the report gives;
    `compare_wrappers` names (X, Y) pairs of rows that are both policies through a test-time
    wrapper (which wrapper does better), reported the same way.
    `clamgen report` reads the scores from those files and aggregates each row over its seeds;
    nothing is copied."""
    runs = [
        {
            "row": row,
            "seed": int(seed),
            "result": Path(os.path.relpath(Path(path).resolve(), out.parent.resolve())).as_posix(),
            "result_row": table2_row_name(path),
        }
        for row, found in rows.items()
        for seed, path in found
    ]
    data = {"kind": SEED_SET_KIND, "command": command, "note": note, "runs": runs}
    for key, pairs in (("compare", compare), ("compare_wrappers", compare_wrappers)):
        unknown = {row for pair in pairs for row in pair} - set(rows)
        if unknown:
            raise ValueError(f"{key} names rows not in the set: {sorted(unknown)}")
        if pairs or key == "compare":
            data[key] = [list(pair) for pair in pairs]
    out.write_text(json.dumps(data, indent=1) + "\n")
    return out


def probability_of_improvement(
    scores: Mapping[str, np.ndarray],
    pairs: Sequence[tuple[str, str]],
    reps: int = POI_REPS,
    seed: int = DEFAULT_SEED,
) -> dict[tuple[str, str], Estimate]:
    """P(X > Y) for each pair (X, Y) of row names: the probability that a run of X scores higher
    than a run of Y on a condition (ties count one half; Mann-Whitney U over both rows' runs),
    averaged over conditions (`rliable.metrics.probability_of_improvement`). Intervals resample
    each row's runs independently (`StratifiedIndependentBootstrap`). Both rows need the same
    conditions in the same order."""
    for x, y in pairs:
        if scores[x].shape[1] != scores[y].shape[1]:
            raise ValueError(
                f"rows {x!r} and {y!r} have {scores[x].shape[1]} and {scores[y].shape[1]} "
                "conditions; probability of improvement compares the same conditions"
            )
    pair_scores = {f"{x}\x00{y}": [scores[x], scores[y]] for x, y in pairs}
    with seeded_numpy(seed):
        points, intervals = rly.get_interval_estimates(
            pair_scores,
            metrics.probability_of_improvement,
            reps=reps,
            confidence_interval_size=CONFIDENCE,
        )
    out = {}
    for (x, y), key in zip(pairs, pair_scores, strict=True):
        low, high = np.ravel(intervals[key])
        out[(x, y)] = Estimate(float(points[key]), float(low), float(high))
    return out


@dataclass(frozen=True)
class Profile:
    """A performance profile: the fraction of (run, condition) scores above each threshold."""

    taus: np.ndarray
    fraction: np.ndarray
    low: np.ndarray
    high: np.ndarray


def _score_distribution(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """rliable's score distribution (`library.score_distributions`: the fraction of all scores
    above each tau) for every tau at once; rliable's own loops over taus in Python."""
    return np.mean(scores.reshape(-1, 1) > taus.reshape(1, -1), axis=0)


def performance_profiles(
    scores: Mapping[str, np.ndarray],
    taus: np.ndarray = PROFILE_TAUS,
    reps: int = DEFAULT_REPS,
    seed: int = DEFAULT_SEED,
) -> dict[str, Profile]:
    """Each row's score distribution (`rliable.library.create_performance_profile`): the
    fraction of its runs x conditions whose success exceeds tau, with 95% bootstrap bands."""
    taus = np.asarray(taus, dtype=float)
    several = {k: v for k, v in scores.items() if v.shape[0] > 1}
    fractions, intervals = {}, {}
    if several:
        with seeded_numpy(seed):
            fractions, intervals = rly.create_performance_profile(
                several,
                taus,
                custom_profile_func=_score_distribution,
                reps=reps,
                confidence_interval_size=CONFIDENCE,
            )
    for name, matrix in scores.items():
        if name not in several:  # one run: its band is its profile
            fractions[name] = _score_distribution(matrix, taus)
            intervals[name] = np.stack([fractions[name], fractions[name]])
    return {
        name: Profile(taus, np.asarray(fractions[name]), *np.asarray(intervals[name]))
        for name in scores
    }


@dataclass(frozen=True)
class Curve:
    """A row's sample-efficiency curve: IQM and mean over runs at each env step, with bands."""

    steps: np.ndarray
    num_runs: int
    iqm: np.ndarray
    iqm_low: np.ndarray
    iqm_high: np.ndarray
    mean: np.ndarray
    mean_low: np.ndarray
    mean_high: np.ndarray


def align_curves(
    curves: Sequence[tuple[Sequence[int], Sequence[float]]],
) -> tuple[np.ndarray, np.ndarray]:
    """Runs' (steps, values) evaluated at the steps every run has (a run that stopped early or
    evaluates at other steps limits the curve to the common ones): `(steps, (runs, steps))`."""
    if not curves:
        raise ValueError("no curves to align")
    common = set(curves[0][0])
    for steps, _ in curves[1:]:
        common &= set(steps)
    steps = np.array(sorted(common), dtype=np.int64)
    values = np.empty((len(curves), len(steps)))
    for i, (run_steps, run_values) in enumerate(curves):
        by_step = dict(zip(run_steps, run_values, strict=True))
        values[i] = [by_step[s] for s in steps]
    return steps, values


def _per_step_mean_and_iqm(scores: np.ndarray) -> np.ndarray:
    """Mean and IQM at every step of a `(runs, conditions, steps)` array, concatenated: what
    `metrics.aggregate_mean` / `metrics.aggregate_iqm` give on each step's `(runs, conditions)`
    slice (the same 25% `scipy.stats.trim_mean`), in one call per bootstrap replication."""
    flat = scores.reshape(-1, scores.shape[-1])
    return np.concatenate([flat.mean(axis=0), scipy.stats.trim_mean(flat, 0.25, axis=0)])


def sample_efficiency_curves(
    curves: Mapping[str, Sequence[tuple[Sequence[int], Sequence[float]]]],
    reps: int = DEFAULT_REPS,
    seed: int = DEFAULT_SEED,
) -> dict[str, Curve]:
    """Per row, success against env steps over its runs: IQM and mean at every common step with
    95% stratified-bootstrap bands (rliable's sample-efficiency recipe: one interval estimate of
    a per-step aggregate on a `(runs, 1, steps)` array). Rows whose runs share no step are
    left out."""
    arrays, step_lists = {}, {}
    for name, run_curves in curves.items():
        steps, values = align_curves(run_curves)
        if len(steps):
            arrays[name], step_lists[name] = values[:, None, :], steps

    points, intervals = _interval_estimates(arrays, _per_step_mean_and_iqm, reps, seed)
    out = {}
    for name, steps in step_lists.items():
        n = len(steps)
        point, (low, high) = points[name], intervals[name]
        out[name] = Curve(
            steps=steps,
            num_runs=arrays[name].shape[0],
            mean=point[:n],
            mean_low=low[:n],
            mean_high=high[:n],
            iqm=point[n:],
            iqm_low=low[n:],
            iqm_high=high[n:],
        )
    return out
