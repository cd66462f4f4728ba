"""`clamgen report`: one Markdown page from the files under `results/`, beside the paper.

Reads (whatever exists):
- sweep summaries (`clamgen sweep`; any `results/**/*.json` of kind `clamgen-sweep`, or
  `--sweep PATH`): every run's test scores and validation curve, several seeds per row;
- seed sets (any `results/**/*.json` of kind `clamgen-seeds`, written by the scripts that train
  and evaluate several seeds of a recipe outside a sweep, `aggregate.write_seed_set`): a row's
  runs, each a training seed and the `clamgen eval --table 2` file (and row in it) that holds
  its test scores;
- `results/**/table1_*.json` (from `clamgen eval --table 1`) and `results/table2/*.json`
  (`clamgen eval --table 2`): single runs, used for rows that no sweep or seed set covers (a
  table row that a seed set counts as one of its runs is not a row of its own); their curves
  come from the `metrics.csv` of the run directory under `results/` named like the policy's;
- `results/benchmarks/*.csv` (speed comparisons, each against a named reference).
Writes `REPORT.md` and `figures/*.png` into the results directory: the tables as measured, one
figure per task family (reach, image-only reach, obstacles, blocked) with sample-efficiency
curves, test success over seeds and performance profiles, the aggregate table with 95%
stratified-bootstrap intervals (rliable) and seed counts, the probability that full CLAMGen
improves on each ablation, and the speed table.
"""

from __future__ import annotations

import csv
import json
import textwrap
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import matplotlib
import numpy as np
import tyro

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.colors import to_rgba

from clamgen.experiments import aggregate as agg
from clamgen.experiments.tables import (
    PAPER_TABLE1,
    PAPER_TABLE2,
    ObstacleRow,
    SpeedRow,
    table1_markdown,
    table2_markdown,
)

# Columns of a family figure's legend (row names are long), and about how many characters of
# the legend's 8-point text fit across the 18-inch figure.
LEGEND_COLUMNS = 3
LEGEND_CHARACTERS = 300
# Row names longer than this wrap onto further lines beside panel (a), which would otherwise
# take most of the figure's width.
TICK_LABEL_CHARACTERS = 70
CURVE_METRIC = "eval/success_rate"
# Task families, one figure and one aggregate table each; conditions are what a run's score
# is split over (Table 1: the target speeds; Table 2: one family each).
FAMILIES = {
    "reach": "Reach, joint observations (Table 1)",
    "image-only": "Reach from images only (Table 1)",
    "obstacles": "Standard obstacle tasks (Table 2)",
    "blocked": "Blocked-path tasks (Table 2)",
}
ENV_FAMILY = {
    "CLAMGen/Reach-v0": "reach",
    "CLAMGen/ReachObstacles-v0": "obstacles",
    "CLAMGen/ReachBlocked-v0": "blocked",
}
# The mix of blocked and standard tasks: its runs validate on mixed tasks, and their curves are
# drawn (dashed) in the figures of both families it mixes.
MIXED_ENV = "CLAMGen/ReachMixed-v0"
MIXED_FAMILIES = ("obstacles", "blocked")
SWEEP_KIND = "clamgen-sweep"
TABLE1_ROW = {"joints": "joint policy", "images": "image-only policy (2 views)"}
# Which row full CLAMGen is for each ablation of the paper's Table 2 (same views).
DEFAULT_COMPARISONS = {
    "no residual (2 views)": "CLAMGen, 2 RGBD views",
    "no HER (2 views)": "CLAMGen, 2 RGBD views",
    "no view dropout (2 views)": "CLAMGen, 2 RGBD views",
    "no collision loss (2 views)": "CLAMGen, 2 RGBD views",
    "vanilla CURL + HER (3 views)": "CLAMGen, 3 RGBD views",
}
ROW_ORDER = [*TABLE1_ROW.values(), *PAPER_TABLE2]
# Qualitative colours, one per row, in row order: tab10 first, then tab20's lighter shades, then
# two shades of each of tab20b's five hues and tab20c's four (its greys left out): 38 in all,
# as many distinct colours as a figure of every Table 2 row needs.
PALETTE = (
    [plt.get_cmap("tab10")(i) for i in range(10)]
    + [plt.get_cmap("tab20")(i) for i in range(1, 20, 2)]
    + [plt.get_cmap("tab20b")(i) for i in range(0, 20, 2)]
    + [plt.get_cmap("tab20c")(i) for i in range(0, 16, 2)]
)
# Row names on the success panel are written in their row's colour, darkened by this share
# towards black so that the light shades stay readable on white.
LABEL_DARKEN = 0.35


@dataclass(frozen=True)
class ReportConfig:
    """Build the results page from the files under a results directory."""

    results_dir: Annotated[Path, tyro.conf.arg(aliases=("--results",))] = Path("results")
    """Directory holding tables, sweep summaries, training metrics and benchmark CSVs
    (absolute, or relative to the current directory); the page goes here."""
    sweep: tuple[Path, ...] = ()
    """Sweep summaries to read besides those found under the results directory."""
    reps: int = agg.DEFAULT_REPS
    """Bootstrap replications per interval."""
    seed: int = agg.DEFAULT_SEED
    """Seed of the bootstrap (the page is the same for the same inputs and seed)."""


# ------------------------------------------------------------------- single results
def load_table1(path: Path) -> tuple[list[SpeedRow], dict]:
    data = json.loads(path.read_text())
    return [SpeedRow(**row) for row in data["rows"]], data


def load_table2_rows(directory: Path) -> list[ObstacleRow]:
    rows = []
    for path in sorted(directory.glob("*.json")):
        data = json.loads(path.read_text())
        rows += [ObstacleRow(**row) for row in data["rows"]]
    rows.sort(key=lambda row: _row_rank(row.name))
    return rows


def read_curve(metrics_csv: Path, metric: str = CURVE_METRIC) -> tuple[list[int], list[float]]:
    steps, values = [], []
    with metrics_csv.open() as f:
        for row in csv.DictReader(f):
            if row["metric"] == metric:
                steps.append(int(row["step"]))
                values.append(float(row["value"]))
    return steps, values


def _row_rank(name: str) -> int:
    return ROW_ORDER.index(name) if name in ROW_ORDER else len(ROW_ORDER)


# ------------------------------------------------------------------------ run results
@dataclass
class RunResult:
    """One trained policy's test scores (per condition) and validation curve."""

    row: str
    table: int
    observation: str
    scores: dict[str, float]
    """Test success per condition: target speed label (Table 1) or task family (Table 2)."""
    curve: tuple[list[int], list[float]] = field(default_factory=lambda: ([], []))
    seed: int | None = None
    """Training seed; None for baselines (nothing trained)."""
    train_env: str | None = None
    source: str = ""

    def families(self) -> list[str]:
        if self.table == 1:
            return ["image-only" if self.observation == "images" else "reach"]
        return [f for f in self.scores if f in FAMILIES]

    def family_scores(self, family: str) -> dict[str, float]:
        return self.scores if self.table == 1 else {family: self.scores[family]}

    @property
    def curve_families(self) -> tuple[str, ...]:
        """The families whose figures show the validation curve: the one whose validation tasks
        it is measured on, or both families of the mix for runs trained on mixed tasks."""
        if self.train_env == MIXED_ENV:
            return MIXED_FAMILIES
        family = ENV_FAMILY.get(self.train_env or "")
        if family == "reach" and self.observation == "images":
            return ("image-only",)
        return (family,) if family else ()


def _run_config(run_dir: Path | None) -> dict:
    path = None if run_dir is None else run_dir / "config.json"
    return json.loads(path.read_text()) if path and path.is_file() else {}


def _speed_label(speed: Any) -> str:
    return "variable" if speed == "variable" else f"{float(speed):g}"


def results_from_sweeps(paths: Iterable[Path]) -> tuple[list[RunResult], dict[str, str]]:
    """Finished runs of sweep summaries, and the rows' `compare_to` (row -> reference row).
    A row and training seed that two summaries share (a run copied into a second sweep as the
    row its ablations compare to) counts once, from the first summary."""
    results, comparisons = [], {}
    seen: set[tuple[str, Any]] = set()
    for path in paths:
        summary = json.loads(path.read_text())
        for row in summary.get("rows", []):
            if row.get("compare_to"):
                comparisons[row["name"]] = row["compare_to"]
        for run in summary["runs"]:
            test = run.get("test")
            if run.get("status") != "done" or not test or (run["row"], run.get("seed")) in seen:
                continue
            seen.add((run["row"], run.get("seed")))
            validation = run.get("validation") or {}
            results.append(
                RunResult(
                    row=run["row"],
                    table=test["table"],
                    observation=test.get("observation", "joints"),
                    scores=dict(test["scores"]),
                    curve=(validation.get("steps", []), validation.get("success_rate", [])),
                    seed=run.get("seed"),
                    train_env=run.get("train_env"),
                    source=str(path),
                )
            )
    return results, comparisons


def _run_dir_for(root: Path, policy: str, result_file: Path) -> Path | None:
    """The directory under `root` holding the metrics of the run that made `policy`: the result
    file's own directory, or one named like the policy file's run directory."""
    if (result_file.parent / "metrics.csv").is_file():
        return result_file.parent
    name = Path(str(policy).split(" ")[0]).parent.name
    if name:
        for metrics in root.rglob(f"{name}/metrics.csv"):
            return metrics.parent
    return None


def results_from_tables(root: Path) -> list[RunResult]:
    """Single runs from the committed `clamgen eval` results (one seed per row)."""
    results = []
    for path in sorted(root.rglob("table1_*.json")):
        rows, data = load_table1(path)
        observation = data.get("observation", "joints")
        run_dir = _run_dir_for(root, data.get("policy", ""), path)
        scores = {_speed_label(r.speed): r.success_rate for r in rows}
        row = TABLE1_ROW.get(observation, path.stem)
        results.append(_single(run_dir, row, 1, observation, scores, path))
    table2 = root / "table2"
    for path in sorted(table2.glob("*.json")) if table2.is_dir() else []:
        data = json.loads(path.read_text())
        rows = [ObstacleRow(**row) for row in data["rows"]]
        policy = str(data.get("policy", ""))
        run_dir = _run_dir_for(root, policy, path) if policy.endswith(".pt") else None
        for name in dict.fromkeys(r.name for r in rows):
            scores = {r.family: r.success_rate for r in rows if r.name == name}
            results.append(_single(run_dir, name, 2, "images", scores, path))
    return results


def _single(run_dir, row, table, observation, scores, path) -> RunResult:
    config = _run_config(run_dir)
    curve = read_curve(run_dir / "metrics.csv") if run_dir is not None else ([], [])
    return RunResult(
        row=row,
        table=table,
        observation=observation,
        scores=scores,
        curve=curve,
        seed=(config.get("loop") or {}).get("seed") if run_dir is not None else None,
        train_env=(config.get("env") or {}).get("env_id"),
        source=str(path),
    )


def find_summaries(root: Path, kind: str = SWEEP_KIND) -> list[Path]:
    """The JSON files under `root` of this `kind` (a sweep summary or a seed set)."""
    found = []
    for path in sorted(root.rglob("*.json")):
        if path.stat().st_size > 50 * 2**20:
            continue
        try:
            data = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError):
            continue
        if isinstance(data, dict) and data.get("kind") == kind:
            found.append(path)
    return found


def results_from_seed_sets(paths: Iterable[Path]) -> tuple[list[RunResult], set[tuple[Path, str]]]:
    """The runs of seed sets, and the (result file, row name) pairs they read, which are then no
    single-run rows of their own. A row and seed that two sets share counts once."""
    results, used, seen = [], set(), set()
    for path in paths:
        for run in json.loads(path.read_text())["runs"]:
            result = (path.parent / run["result"]).resolve()
            if not result.is_file():
                raise FileNotFoundError(f"{path}: result file not found: {run['result']}")
            rows = [
                r for r in json.loads(result.read_text())["rows"] if r["name"] == run["result_row"]
            ]
            if not rows:
                raise ValueError(f"{path}: no row {run['result_row']!r} in {run['result']}")
            used.add((result, run["result_row"]))
            if (run["row"], run["seed"]) in seen:
                continue
            seen.add((run["row"], run["seed"]))
            scores = {r["family"]: r["success_rate"] for r in rows}
            results.append(
                RunResult(run["row"], 2, "images", scores, seed=run["seed"], source=str(path))
            )
    return results, used


def seed_set_pairs(paths: Iterable[Path], key: str = "compare") -> list[tuple[str, str]]:
    """The (X, Y) row pairs that seed sets ask to compare, in order, each once: under
    `"compare"`, X a policy through a test-time wrapper and Y the same policies alone; under
    `"compare_wrappers"`, X and Y both through a wrapper."""
    pairs = [tuple(pair) for path in paths for pair in json.loads(path.read_text()).get(key, [])]
    return list(dict.fromkeys(pairs))


def collect_results(
    root: Path, sweeps: Iterable[Path] = (), seed_sets: list[Path] | None = None
) -> tuple[list[RunResult], dict[str, str]]:
    """Every run result; rows covered by a sweep or a seed set take their runs from those only,
    and a table file's row that a seed set reads is no row of its own. `seed_sets`: the seed
    sets under `root` when already found (`find_summaries`)."""
    paths = list(dict.fromkeys([*find_summaries(root, SWEEP_KIND), *map(Path, sweeps)]))
    swept, comparisons = results_from_sweeps(paths)
    if seed_sets is None:
        seed_sets = find_summaries(root, agg.SEED_SET_KIND)
    seeded, used = results_from_seed_sets(seed_sets)
    covered = {r.row for r in swept} | {r.row for r in seeded}
    seeded = [r for r in seeded if r.row not in {s.row for s in swept}]
    single = [
        r
        for r in results_from_tables(root)
        if r.row not in covered and (Path(r.source).resolve(), r.row) not in used
    ]
    return swept + seeded + single, {**DEFAULT_COMPARISONS, **comparisons}


# ------------------------------------------------------------------------- aggregates
@dataclass
class FamilyAggregate:
    family: str
    rows: list[str]
    scores: dict[str, np.ndarray]
    """Row -> (runs, conditions) test success."""
    conditions: list[str]
    seeds: dict[str, list[int | None]]
    stats: dict[str, agg.RowAggregate]
    profiles: dict[str, agg.Profile]
    curves: dict[str, agg.Curve]
    mixed_curves: set[str] = field(default_factory=set)
    """Rows whose curves are validation on the mixed tasks, not on this family's alone."""


def aggregate_family(
    results: list[RunResult], family: str, reps: int, seed: int
) -> FamilyAggregate | None:
    mine = [r for r in results if family in r.families()]
    if not mine:
        return None
    rows = sorted(dict.fromkeys(r.row for r in mine), key=_row_rank)
    conditions = list(dict.fromkeys(c for r in mine for c in r.family_scores(family)))
    scores, seeds = {}, {}
    for row in rows:
        runs = [r for r in mine if r.row == row]
        # A run lacking a condition (evaluated on fewer speeds) is left out of its row.
        runs = [r for r in runs if set(conditions) <= set(r.family_scores(family))]
        if runs:
            scores[row] = agg.score_matrix(
                [[r.family_scores(family)[c] for c in conditions] for r in runs]
            )
            seeds[row] = [r.seed for r in runs]
    rows = [r for r in rows if r in scores]
    curve_runs: dict[str, list] = {}
    mixed: set[str] = set()
    for r in results:
        if family in r.curve_families and r.curve[0] and r.row in scores:
            curve_runs.setdefault(r.row, []).append(r.curve)
            if r.train_env == MIXED_ENV:
                mixed.add(r.row)
    return FamilyAggregate(
        family=family,
        rows=rows,
        scores=scores,
        conditions=conditions,
        seeds=seeds,
        stats=agg.aggregate_rows(scores, reps=reps, seed=seed),
        profiles=agg.performance_profiles(scores, reps=reps, seed=seed),
        curves=agg.sample_efficiency_curves(curve_runs, reps=reps, seed=seed) if curve_runs else {},
        mixed_curves=mixed,
    )


def _paper_value(row: str, family: str) -> float | None:
    if family == "obstacles":
        return PAPER_TABLE2.get(row)
    if family in ("reach", "image-only"):
        paper = PAPER_TABLE1["images" if family == "image-only" else "joints"]
        return float(np.mean([success for success, _ in paper.values()]))
    return None


def _interval(estimate: agg.Estimate, num_runs: int) -> str:
    if num_runs < 2:
        return f"{estimate.value:.3f} (1 run: no interval)"
    return f"{estimate.value:.3f} ({estimate.low:.3f}-{estimate.high:.3f})"


def _seeds_cell(seeds: list[int | None]) -> str:
    known = [s for s in seeds if s is not None]
    if not known:
        return "- (not trained)" if len(seeds) == 1 else f"{len(seeds)} runs"
    return f"{len(seeds)} ({', '.join(map(str, known))})"


def aggregate_markdown(result: FamilyAggregate) -> str:
    conditions = (
        f"the {len(result.conditions)} target speeds ({', '.join(result.conditions)} m/s) pooled"
        if len(result.conditions) > 1
        else "its test tasks"
    )
    lines = [
        f"Each run's score: success on {conditions}. Mean and IQM over runs"
        f"{' x speeds' if len(result.conditions) > 1 else ''} with 95% stratified-bootstrap "
        "intervals (rliable, percentile); seeds are the training seeds.",
        "",
        "| row | runs (training seeds) | mean success (95% CI) | IQM (95% CI) | per run | paper |",
        "|---|---|---|---|---|---|",
    ]
    for row in result.rows:
        stats, matrix = result.stats[row], result.scores[row]
        per_run = ", ".join(f"{v:.3f}" for v in matrix.mean(axis=1))
        paper = _paper_value(row, result.family)
        lines.append(
            f"| {row} | {_seeds_cell(result.seeds[row])} "
            f"| {_interval(stats.mean, stats.num_runs)} | {_interval(stats.iqm, stats.num_runs)} "
            f"| {per_run} | {'-' if paper is None else f'{paper:g}'} |"
        )
    return "\n".join(lines)


POI_TEXT = (
    "P(X > Y): the probability that a run of X succeeds more often than a run of Y on the "
    "same test tasks (ties count one half; rliable's probability of improvement, intervals "
    "from independent stratified bootstraps of both rows' runs)."
)


@dataclass(frozen=True)
class Comparison:
    """How a table of P(X > Y) names its rows (X, Y) and verdicts, and what it says first."""

    text: str
    x: str
    y: str
    p_label: str
    x_better: str
    y_better: str


PAPER_CLAIMS = Comparison(
    POI_TEXT + " The paper claims full CLAMGen beats each ablation; a claim holds here when the "
    "interval lies above 0.5, fails when it lies below, and is undecided when it spans 0.5. It "
    "needs >= 2 runs per row.",
    "full CLAMGen (X)",
    "ablation (Y)",
    "P(full > ablation)",
    "full CLAMGen",
    "ablation",
)
WRAPPERS = Comparison(
    POI_TEXT + " X is a policy acting through a test-time wrapper (beyond the paper), Y the same "
    "seeds' policies alone; the wrapper helps when the interval lies above 0.5. It needs >= 2 "
    "runs per row. Success is a reach with no collision at any step; the collision rates are "
    "in each row's Table 2 file.",
    "with the wrapper (X)",
    "policy alone (Y)",
    "P(X > Y)",
    "the wrapper",
    "the policy alone",
)
BETWEEN_WRAPPERS = Comparison(
    POI_TEXT + " X and Y are policies of the same recipe through two test-time wrappers (beyond "
    "the paper), each row over its own training seeds; X does better when the interval lies "
    "above 0.5, Y when it lies below. It needs >= 2 runs per row. Success is a reach with no "
    "collision at any step; the collision rates are in each row's Table 2 file.",
    "wrapper X",
    "wrapper Y",
    "P(X > Y)",
    "X",
    "Y",
)


def comparison_markdown(
    families: dict[str, FamilyAggregate],
    pairs: Iterable[tuple[str, str]],
    how: Comparison,
    reps: int,
    seed: int,
) -> str | None:
    """P(X > Y) per Table 2 family for each (X, Y) of `pairs` that a family has both rows of,
    with a verdict; None when there is none."""
    shown = [f for f in ("obstacles", "blocked") if f in families]
    pairs = [
        (x, y)
        for x, y in pairs
        if any(x in families[f].scores and y in families[f].scores for f in shown)
    ]
    if not pairs:
        return None
    header = " | ".join(f"{how.p_label}, {f} (95% CI) | verdict, {f}" for f in shown)
    lines = [
        how.text,
        "",
        f"| {how.y} | {how.x} | {header} |",
        "|---|---|" + "---|---|" * len(shown),
    ]
    for x, y in pairs:
        cells = []
        for family in shown:
            scores = families[family].scores
            n_x, n_y = (scores[r].shape[0] if r in scores else 0 for r in (x, y))
            if min(n_x, n_y) < 2:
                cells += [f"- (runs: {n_x} / {n_y})", "needs >= 2 runs per row"]
                continue
            poi = agg.probability_of_improvement(
                scores, [(x, y)], reps=min(reps, agg.POI_REPS), seed=seed
            )[(x, y)]
            verdict = (
                f"holds: {how.x_better} better"
                if poi.low > 0.5
                else f"fails: {how.y_better} better"
                if poi.high < 0.5
                else "undecided"
            )
            cells += [f"{poi.value:.2f} ({poi.low:.2f}-{poi.high:.2f})", verdict]
        lines.append(f"| {y} | {x} | {' | '.join(cells)} |")
    return "\n".join(lines)


def improvement_markdown(
    families: dict[str, FamilyAggregate], comparisons: dict[str, str], reps: int, seed: int
) -> str | None:
    """P(full CLAMGen > ablation) per Table 2 family, with what it says about each claim."""
    pairs = [(reference, ablation) for ablation, reference in comparisons.items()]
    return comparison_markdown(families, pairs, PAPER_CLAIMS, reps, seed)


# ---------------------------------------------------------------------------- figures
def row_colours(rows: Iterable[str]) -> dict[str, Any]:
    """One distinct colour per row, the same in every figure."""
    ordered = sorted(dict.fromkeys(rows), key=lambda r: (_row_rank(r), r))
    return {row: PALETTE[i % len(PALETTE)] for i, row in enumerate(ordered)}


def _darken(colour: Any) -> tuple[float, ...]:
    r, g, b, *_ = to_rgba(colour)
    return tuple(c * (1 - LABEL_DARKEN) for c in (r, g, b))


def plot_family(result: FamilyAggregate, colours: dict[str, Any], out: Path) -> Path:
    """Sample-efficiency curves (validation), test success over runs, performance profiles."""
    n = len(result.rows)
    labels = [textwrap.fill(row, TICK_LABEL_CHARACTERS) for row in result.rows]
    # Rows stand far enough apart for the tallest wrapped label (8-point lines, 0.14 inch).
    row_inches = max(0.32, 0.14 * max(label.count("\n") + 1 for label in labels))
    # The success panel, whose tick labels are the long row names, comes first so that the
    # layout gives them the figure's left margin; constrained layout keeps every title inside.
    fig, (success_ax, curves_ax, profile_ax) = plt.subplots(
        1, 3, figsize=(18, max(5.5, 2.6 + row_inches * n)), layout="constrained",
        gridspec_kw={"width_ratios": [1, 1.1, 1]},
    )  # fmt: skip
    fig.suptitle(FAMILIES[result.family], fontsize=13)
    # (b) validation success against env steps: IQM over runs, band = its 95% interval.
    for row in result.rows:
        curve = result.curves.get(row)
        if curve is None:
            continue
        colour, style = colours[row], "--" if row in result.mixed_curves else "-"
        curves_ax.plot(curve.steps, curve.iqm, style, color=colour, lw=1.8, marker="o", ms=2.5)
        if curve.num_runs > 1:
            curves_ax.fill_between(
                curve.steps, curve.iqm_low, curve.iqm_high, color=colour, alpha=0.2, lw=0
            )
    # Titles in short lines: the panels stand close, and a long line runs into its neighbour.
    title = "(b) validation success\nduring training:\nIQM over runs, 95% band"
    if result.mixed_curves:
        title += "\ndashed: on mixed tasks"
    curves_ax.set_title(title, fontsize=10)
    curves_ax.set_xlabel("environment steps")
    curves_ax.set_ylabel("success rate (validation tasks)")
    curves_ax.set_ylim(-0.02, 1.02)
    curves_ax.grid(alpha=0.3)
    if not result.curves:
        curves_ax.text(0.5, 0.5, "no training curves\non these tasks", ha="center",
                       va="center", transform=curves_ax.transAxes, color="0.4")  # fmt: skip
    # (a) test success per row: IQM with its interval, every run as a dot, the paper as x.
    y = np.arange(n)[::-1]
    for yi, row in zip(y, result.rows, strict=True):
        colour, stats = colours[row], result.stats[row]
        per_run = result.scores[row].mean(axis=1)
        jitter = np.linspace(-0.12, 0.12, len(per_run)) if len(per_run) > 1 else [0.0]
        success_ax.scatter(per_run, yi + np.asarray(jitter), s=14, color=colour, alpha=0.6)
        success_ax.errorbar(
            stats.iqm.value, yi, xerr=[[stats.iqm.value - stats.iqm.low],
                                       [stats.iqm.high - stats.iqm.value]],
            fmt="D", color=colour, ms=6, capsize=3, lw=2,
        )  # fmt: skip
        success_ax.text(1.03, yi, f"n={stats.num_runs}", va="center", fontsize=8)
        paper = _paper_value(row, result.family)
        if paper is not None:
            success_ax.scatter([paper], [yi], marker="x", color="black", s=30, zorder=3)
    success_ax.set_yticks(y, labels, fontsize=8)
    for tick, row in zip(success_ax.get_yticklabels(), result.rows, strict=True):
        tick.set_color(_darken(colours[row]))
    success_ax.set_xlim(-0.02, 1.12)
    success_ax.set_ylim(-0.6, n - 0.4)  # runs' dots stay beside their row, even for one row
    success_ax.set_xlabel("test success rate")
    success_ax.set_title(
        "(a) test success:\nIQM (diamond, 95% CI),\nruns (dots), paper (x)", fontsize=10
    )
    success_ax.grid(alpha=0.3, axis="x")
    # (c) performance profile: fraction of runs x conditions above each success threshold. A
    # single run's profile is one step at its score, the dot of (a) again: where some rows have
    # several runs, only theirs are drawn, so that the panel stays readable.
    profiled = [r for r in result.rows if result.stats[r].num_runs > 1] or result.rows
    for row in profiled:
        profile, colour = result.profiles[row], colours[row]
        profile_ax.plot(profile.taus, profile.fraction, color=colour, lw=1.6)
        if result.stats[row].num_runs > 1:
            profile_ax.fill_between(
                profile.taus, profile.low, profile.high, color=colour, alpha=0.15, lw=0
            )
    profile_ax.set_title(
        "(c) performance profile\n(95% band)"
        + ("\nrows with several runs" if len(profiled) < len(result.rows) else ""),
        fontsize=10,
    )
    profile_ax.set_xlabel("test success threshold tau")
    profile_ax.set_ylabel("fraction of runs with success > tau")
    profile_ax.set_ylim(-0.02, 1.02)
    profile_ax.grid(alpha=0.3)
    # The legend names the lines of (b) and (c); (a) names its rows itself.
    drawn = [r for r in result.rows if r in result.curves or r in profiled]
    handles = [plt.Line2D([], [], color=colours[r], lw=3) for r in drawn]
    # As many columns (at most three) as the longest row name lets fit in the figure's width.
    fitting = LEGEND_CHARACTERS // (max(len(r) for r in drawn) + 8)
    columns = max(1, min(LEGEND_COLUMNS, len(drawn), fitting))
    fig.legend(handles, drawn, loc="outside lower center", ncol=columns, fontsize=8,
               frameon=False)  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out


# ------------------------------------------------------------------------------ speed
@dataclass(frozen=True)
class SpeedEntry:
    """One speed comparison: what was measured, ours, the reference, their ratio."""

    measurement: str
    ours: str
    reference: str
    reference_value: str
    ratio: float | None
    ratio_meaning: str
    source: str
    label: str = ""
    """Short name of the comparison for the figure (default: the measurement)."""


SHORT_NAMES = {"env_steps": "env steps", "render": "rendering", "render_pretty": "pretty rendering"}
PYBULLET = "PyBullet, the paper's simulator: same scene and tasks (benchmarks/pybullet_scene.py)"


def _f(row: dict, key: str) -> float | None:
    try:
        return float(row[key])
    except (KeyError, TypeError, ValueError):
        return None


def _reference_row(rows: list[dict], ratio_key: str) -> dict | None:
    """The row a benchmark measured the others against: the one whose ratio is exactly 1."""
    return next((r for r in rows if _f(r, ratio_key) == 1.0), None)


def speed_entries(directory: Path) -> list[SpeedEntry]:
    """The benchmark CSVs as comparisons that name their reference (benchmarks/<file>.py
    documents each measurement)."""
    entries = []
    for path in sorted(directory.glob("*.csv")):
        with path.open() as f:
            rows = list(csv.DictReader(f))
        entries += _describe(path.stem, rows, path.name)
    return entries


def _describe(stem: str, rows: list[dict], source: str) -> list[SpeedEntry]:
    if stem in ("env_steps", "render", "render_pretty"):
        what = {
            "env_steps": ("env steps/s, joint observations, 2 obstacles", PYBULLET),
            "render": ("3-view 128 px RGBD frames/s", f"{PYBULLET}, TinyRenderer"),
            "render_pretty": (
                "3-view 128 px RGBD frames/s, shadows and lighting on",
                f"{PYBULLET}, TinyRenderer",
            ),
        }[stem]
        return [
            SpeedEntry(
                what[0],
                f"{float(r['clamgen_per_s']):.0f}/s",
                what[1],
                f"{float(r['pybullet_per_s']):.0f}/s",
                _f(r, "ratio"),
                "ours / reference (higher: ours faster)",
                source,
                f"{SHORT_NAMES[stem]} vs PyBullet",
            )
            for r in rows
        ]
    if stem == "sb3_her":
        ours = next((r for r in rows if r.get("method") == "clamgen"), None)
        ref = next((r for r in rows if r.get("method") == "sb3"), None)
        if ours and ref:
            target = ours.get("target", "?")
            ref_steps = ref.get("steps_to_target") or "not reached in the budget"
            return [
                SpeedEntry(
                    f"wall time to {target} success on CLAMGen/Reach-v0 (SAC + HER)",
                    f"{float(ours['seconds']):.0f} s ({ours.get('steps_to_target')} steps)",
                    "Stable-Baselines3 SAC + HerReplayBuffer, same env, budget and settings",
                    f"{float(ref['seconds']):.0f} s (steps: {ref_steps})",
                    _f(ours, "ratio_sb3_over_ours"),
                    "reference / ours (higher: ours faster)",
                    source,
                    f"time to {target} success vs Stable-Baselines3",
                )
            ]
    if stem == "encoder_cost":
        entries = []
        for r in rows:
            same_batch = [q for q in rows if q.get("batch") == r.get("batch")]
            reference = _reference_row(same_batch, "speedup_vs_reference")
            if reference is r:
                continue
            entries.append(
                SpeedEntry(
                    f"stage-2 encoder forward + backward, {r['views']} views, {r['image_px']} px, "
                    f"strides {r['strides']}, batch {r['batch']}",
                    f"{float(r['fwd_bwd_ms']):.0f} ms",
                    "the paper-like encoder (84 px, strides 2-1-1-1) at the same batch, same run",
                    "-" if reference is None else f"{float(reference['fwd_bwd_ms']):.0f} ms",
                    _f(r, "speedup_vs_reference"),
                    "reference / ours (higher: ours faster)",
                    source,
                    f"encoder {r['image_px']} px, strides {r['strides']}, batch {r['batch']} "
                    "vs paper-like",
                )
            )
        return entries
    if stem == "checkpoint_stall":
        return [
            SpeedEntry(
                f"training stall of one checkpoint, {r['replay_gib']} GiB image replay",
                f"{float(r['new_stall_s']):.2f} s",
                "the previous two-file checkpoint (one .npz of the whole replay), same buffer",
                f"{float(r['old_save_s']):.2f} s",
                _f(r, "stall_ratio_old_over_new"),
                "reference / ours (higher: ours stalls less)",
                source,
                f"checkpoint stall, {r['replay_gib']} GiB replay, repeat {r.get('repeat', 0)}, "
                "vs two-file",
            )
            for r in rows
        ]
    if stem.startswith("act_latency"):
        condition = _act_latency_condition(stem)
        reference = _reference_row(rows, "ratio_to_reference")
        entries = []
        for r in rows:
            if r is reference:
                continue
            ratio = _f(r, "ratio_to_reference")
            entries.append(
                SpeedEntry(
                    f"acting time per step of `{r['policy']}` (batch 1, one core; aim < 2 ms)"
                    + condition,
                    f"{float(r['median_ms']):.2f} ms median, p95 {float(r['p95_ms']):.2f} ms",
                    "the RL-trained 2-view vision residual (the paper's method), same run",
                    "-" if reference is None else f"{float(reference['median_ms']):.2f} ms",
                    None if not ratio else 1.0 / ratio,
                    "reference / ours (higher: ours faster)",
                    source,
                    f"acting, {r['policy']} vs RL 2-view residual",
                )
            )
        return entries
    if stem == "reset_cost":
        return [
            SpeedEntry(
                "reset of `CLAMGen/ReachBlocked-v0` (sampling a blocked-path task), median",
                f"{float(r['blocked_median_ms']):.1f} ms (p95 {float(r['blocked_p95_ms']):.0f} ms)",
                "reset of `CLAMGen/ReachObstacles-v0`, same run",
                f"{float(r['obstacles_median_ms']):.1f} ms",
                None if not _f(r, "ratio_median") else 1.0 / float(r["ratio_median"]),
                "reference / ours (higher: ours faster; below 1: a blocked reset costs more)",
                source,
                "blocked-task reset vs obstacle-task reset",
            )
            for r in rows
        ]
    if stem == "update_cost":
        reference = _reference_row(rows, "speedup_vs_reference")
        return [
            SpeedEntry(
                f"stage-2 update ({r['preset']}, batch {r['batch']}, {r['threads']} thread): "
                f"{r['option']}",
                f"{float(r['ms_per_update']):.1f} ms",
                "the stage-2 update before its rebuild"
                + (f" ({reference['option']})" if reference else "")
                + ", same run",
                "-" if reference is None else f"{float(reference['ms_per_update']):.1f} ms",
                _f(r, "speedup_vs_reference"),
                "reference / ours (higher: ours faster)",
                source,
                f"update: {r['option'][:40]}",
            )
            for r in rows
            if r is not reference
        ]
    if stem == "concurrent_jobs":
        return [_concurrent_job(r, source) for r in rows]
    if stem == "first_act":
        return [
            SpeedEntry(
                f"first act of a fresh process, `{r['policy']}`"
                + (" (page cache dropped)" if r["page_cache_dropped"] == "True" else "")
                + f", median of {r['processes']}",
                f"{float(r['first_ms']):.1f} ms",
                "the same without the policy's warm-up at its first reset, same run",
                f"{float(r['reference_first_ms']):.1f} ms",
                _f(r, "ratio"),
                "reference / ours (higher: ours faster)",
                source,
                "first act, warm-up vs none",
            )
            for r in rows
        ]
    if stem == "pool_gather":
        return [
            SpeedEntry(
                f"gathering a {r['batch_rows']}-row regression batch from a pool cache on disk "
                f"({r['cache_gib']} GiB file, page cache dropped before each gather), median",
                f"{float(r['read_ahead_ms']):.1f} ms",
                "the same rows read by page faults alone (the memory map as `np.load` gives it)",
                f"{float(r['page_faults_ms']):.1f} ms",
                _f(r, "ratio"),
                "reference / ours (higher: ours faster)",
                source,
                "pool batch gather vs page faults",
            )
            for r in rows
        ]
    # Unknown layout: every field as written, the reference as its script documents it.
    return [
        SpeedEntry(
            ", ".join(f"{k}={v}" for k, v in r.items() if k != "machine" and v != ""),
            "-",
            f"see benchmarks/{stem}.py",
            "-",
            next((_f(r, k) for k in r if "ratio" in k or "speedup" in k), None),
            "as in the file",
            source,
        )
        for r in rows
    ]


def _act_latency_condition(stem: str) -> str:
    """What an `act_latency` CSV's name adds to its measurement (`benchmarks/act_latency.py`
    writes `act_latency[_in_episodes][_noise_k<K>]`, K's point as "p"): "" for the plain one."""
    words = []
    rest = stem.removeprefix("act_latency")
    if rest.startswith("_in_episodes"):
        words.append("timed in live episodes")
        rest = rest.removeprefix("_in_episodes")
    if rest.startswith("_noise_k"):
        noise = rest.removeprefix("_noise_k").replace("p", ".")
        words.append(f"depth noise sd {noise} z^2 m, shields told it")
    return "".join(f", {word}" for word in words)


def _concurrent_job(r: dict, source: str) -> SpeedEntry:
    """A `concurrent_jobs.csv` row: wall time a job with one BLAS thread (the package default)
    against OpenBLAS's own default of a thread per core."""
    at_once = int(r["jobs_at_once"])
    if r["job"] == "training":
        job = f"a short stage-2 training run ({r['env_steps_per_job']} env steps)"
    else:
        job = f"an evaluation of {r['episodes_per_job']} blocked-path episodes"
    how = {1: "one alone", 2: "two at once"}.get(at_once, f"{at_once} at once")
    return SpeedEntry(
        f"wall time of {job}, {how} (median per job)",
        f"{float(r['default_s']):.2f} s",
        "numpy's BLAS with a thread per core (OpenBLAS's default), same run",
        f"{float(r['reference_s']):.2f} s",
        _f(r, "ratio"),
        "reference / ours (higher: ours faster)",
        source,
        f"{r['job']}, {at_once} at once, one BLAS thread vs per core",
    )


def speed_markdown(entries: list[SpeedEntry]) -> str:
    lines = [
        "| measurement | ours | reference (measured in the same run) | reference | ratio | file |",
        "|---|---|---|---|---|---|",
    ]
    for e in entries:
        ratio = "-" if e.ratio is None else f"{e.ratio:.2f}x ({e.ratio_meaning})"
        lines.append(
            f"| {e.measurement} | {e.ours} | {e.reference} | {e.reference_value} | {ratio} "
            f"| `{e.source}` |"
        )
    return "\n".join(lines)


def plot_speed(entries: list[SpeedEntry], out: Path) -> Path | None:
    bars = [(e, e.ratio) for e in entries if e.ratio is not None]
    if not bars:
        return None
    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.3 * len(bars)))
    labels = [e.label or e.measurement[:60] for e, _ in bars]
    values = [v for _, v in bars]
    colours = ["tab:green" if v >= 1 else "tab:red" for v in values]
    y = np.arange(len(bars))[::-1]
    ax.barh(y, values, color=colours)
    ax.set_yticks(y, labels, fontsize=8)
    ax.axvline(1.0, color="k", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("speed-up over the reference (x, log scale; > 1: ours faster)")
    for yi, value in zip(y, values, strict=True):
        ax.text(value, yi, f" {value:.2f}x", va="center", fontsize=8)
    ax.set_xlim(min(0.5, min(values) / 1.5), max(values) * 4)  # room for the largest label
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


# ------------------------------------------------------------------------------- page
def build_report(config: ReportConfig) -> Path:
    """Write REPORT.md (and figures) into `config.results_dir`; returns the page's path."""
    root = config.results_dir
    if not root.is_dir():
        raise FileNotFoundError(
            f"results directory not found: {root.resolve()} (pass --results DIR)"
        )
    for path in config.sweep:
        if not Path(path).is_file():
            raise FileNotFoundError(f"sweep summary not found: {path}")
    figures = root / "figures"
    lines = [
        "# CLAMGen results",
        "",
        "Generated by `clamgen report` from the files under `results/`; every number below is "
        "read from them, and each file's directory holds the config and command that made it.",
        "",
    ]
    table1_files = sorted(root.rglob("table1_*.json"))
    if table1_files:
        lines += ["## Table 1: reaching static and moving targets (no obstacles)", ""]
        for path in table1_files:
            rows, data = load_table1(path)
            lines += [
                f"`{path.relative_to(root)}`: policy `{data.get('policy')}`, "
                f"{data.get('num_tasks')} held-out tasks per row, made by "
                f"`{data.get('command', '?')}`.",
                "",
                table1_markdown(rows, data.get("observation", "joints")),
                "",
            ]
    table2_rows = load_table2_rows(root / "table2") if (root / "table2").is_dir() else []
    if table2_rows:
        lines += [
            "## Table 2: static targets past two obstacles",
            "",
            f"{table2_rows[0].num_tasks} held-out tasks per row; success = reached with no "
            "collision at any step. Rows from `results/table2/*.json`.",
            "",
            table2_markdown(table2_rows),
            "",
        ]
    seed_set_paths = find_summaries(root, agg.SEED_SET_KIND)
    results, comparisons = collect_results(root, config.sweep, seed_set_paths)
    set_sources = set(map(str, seed_set_paths))
    families = {}
    for family in FAMILIES:
        aggregate = aggregate_family(results, family, config.reps, config.seed)
        if aggregate is not None:
            families[family] = aggregate
    if families:
        sources = sorted({Path(r.source).name for r in results if r.source.endswith(".json")})
        sweeps = sorted({r.source for r in results if r.source in map(str, config.sweep)})
        lines += [
            "## Over training seeds: intervals, figures, ablations",
            "",
            f"{len(results)} trained or baseline policies from {len(sources)} result files"
            f"{' and the sweep summaries ' + ', '.join(sweeps) if sweeps else ''}. A row with "
            "one run has no interval: its spread over training seeds is not measured. Curves "
            "are validation success (validation seeds, logged during training; dashed for "
            "runs trained and validated on the mix of blocked and standard tasks, drawn in "
            "both obstacle figures); the tables and profiles use the test seeds. Where some "
            "rows of a figure have several runs, its performance profiles show those rows only "
            "(a single run's profile is one step at its score).",
            "",
        ]
        seed_sets = sorted({Path(r.source) for r in results if r.source in set_sources})
        if seed_sets:
            lines += ["Rows evaluated on several seeds outside a sweep (seed sets):", ""]
            for path in seed_sets:
                data = json.loads(path.read_text())
                lines.append(f"- `{path.relative_to(root)}` (`{data['command']}`): {data['note']}")
            lines.append("")
        colours = row_colours(r for f in families.values() for r in f.rows)
        for family, aggregate in families.items():
            figure = plot_family(aggregate, colours, figures / f"family_{family}.png")
            lines += [
                f"### {FAMILIES[family]}",
                "",
                aggregate_markdown(aggregate),
                "",
                f"![{family}]({figure.relative_to(root)})",
                "",
            ]
        improvement = improvement_markdown(families, comparisons, config.reps, config.seed)
        if improvement:
            lines += ["### Does each component help?", "", improvement, ""]
        pairs = seed_set_pairs(seed_set_paths)
        wrappers = comparison_markdown(families, pairs, WRAPPERS, config.reps, config.seed)
        if wrappers:
            lines += ["### What the test-time wrappers add (beyond the paper)", "", wrappers, ""]
        pairs = seed_set_pairs(seed_set_paths, "compare_wrappers")
        between = comparison_markdown(families, pairs, BETWEEN_WRAPPERS, config.reps, config.seed)
        if between:
            lines += ["### Which test-time wrapper does better (beyond the paper)", "", between, ""]
    entries = speed_entries(root / "benchmarks") if (root / "benchmarks").is_dir() else []
    if entries:
        lines += [
            "## Speed",
            "",
            "Each measurement against the reference it names, both measured in the same run "
            "on the same machine (`benchmarks/<file>.py` describes each).",
            "",
            speed_markdown(entries),
        ]
        speed = plot_speed(entries, figures / "speed.png")
        if speed:
            lines += ["", f"![speed-ups]({speed.relative_to(root)})"]
        lines.append("")
    page = root / "REPORT.md"
    page.write_text("\n".join(lines))
    return page
