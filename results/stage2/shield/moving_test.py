"""A moving target on the test tasks: the shipped residuals alone and in their hybrids against
RRT on the depth map (sessions 43-44; protocols in README.md, "A moving target on the test
tasks", "Session 44: the moving-target rows over training seeds" and "Session 44: RRT on the
depth map meeting a moving target").

    python results/stage2/shield/moving_test.py

Reads `moving/<row>-<views>-<speed>.json` (`moving/run.sh`: the shipped residuals, training
seed 5, and the planners) and `moving/seeds/<row>-<views>-seed<S>-<speed>.json`
(`moving/seeds.sh`: the other committed training seeds) and `moving/realtime/*.json`
(`moving/realtime.sh`), and writes `moving_test.md` beside this file: the two depth-map
planners (to where the target was, session 43; meeting it, session 44); the residuals alone
and in their hybrids as means over training seeds, with rliable's 95% stratified-bootstrap
interval; the rows run in real time beside the same rows without; and, for the shipped seed,
task by task against each planner (only the row solves / only the planner, exact two-sided
sign test; median steps of each on the tasks both solve).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from base_control import rows, write_markdown  # (this directory: the script's own)

from clamgen.experiments.aggregate import aggregate_rows
from clamgen.experiments.policies import views_suffix
from clamgen.experiments.tables import paired_count

HERE = Path(__file__).resolve().parent
RUNS = HERE / "moving"
SPEEDS = ("0p1", "0p2")
"""The target speeds run, as the files spell them (0.1 and 0.2 m/s)."""
FAMILIES = ("obstacles", "blocked")
ALONE = ("residual", "the residual alone")
HYBRID_STALE = ("hybrid", "the residual in its hybrid, planning to where the target is")
HYBRID_TRACK = ("hybrid-track", "the residual in its hybrid, meeting the target")
PLANNERS = (
    ("depth-rrt", "to where the target was (session 43)"),
    ("depth-rrt-track", "meeting the target (session 44)"),
)
PAIRS_AGAINST = {"depth-rrt": (ALONE, HYBRID_STALE), "depth-rrt-track": (ALONE, HYBRID_TRACK)}
"""The rows set task by task against each planner: session 43's, and session 44's."""
REAL_TIME = (
    ("depth-rrt-track", "RRT on the depth map, meeting the target"),
    ("depth-rrt-track-latency", "the same, expecting its own latency"),
    HYBRID_TRACK,
    ("hybrid-track-latency", "the same, its planner expecting its own latency"),
    ALONE,
)
"""The rows run in real time (`moving/realtime.sh`), 0.2 m/s; a `-latency` row's planner
expects its own latency, which changes nothing without real time (its row without it is the
same stem's without `-latency`)."""
ARRIVAL = HERE / "arrival"
STATIC = {
    "depth-rrt-track": ("RRT on the depth map", "depth-rrt-{}.json"),
    "hybrid-track": ("the residual in its hybrid", "hybrid-{}.json"),
}
"""The rows run in real time with static targets (`moving/realtime.sh 0`): their words and
the same row acting in no simulated time, as session 43 re-ran it recording each task's steps
(`arrival/`; the same outcomes as the committed Table 2 rows on all but 0-7 tasks of 200)."""
SHIPPED_SEED = 5
SEEDS = {3: (7, 8, 9), 2: (11, 12), 1: (11, 12)}
"""The other training seeds with committed policies (`moving/seeds.sh`)."""


def speed_of(speed: str) -> str:
    return speed.replace("p", ".")


def seed_files(stem: str, views: int, speed: str) -> list[tuple[int, Path]]:
    """(training seed, file) of a row's evaluations that exist, the shipped seed first."""
    suffix = views_suffix(views)
    files = [(SHIPPED_SEED, RUNS / f"{stem}-{suffix}-{speed}.json")]
    files += [(s, RUNS / "seeds" / f"{stem}-{suffix}-seed{s}-{speed}.json") for s in SEEDS[views]]
    return [(seed, path) for seed, path in files if path.exists()]


def rates(row: dict) -> str:
    return f"{row['success_rate']:.3f} / {row['collision_rate']:.3f}"


def over_seeds(values: list[float]) -> str:
    """Mean over seeds with its 95% interval (none from one seed)."""
    if len(values) == 1:
        return f"{values[0]:.3f}"
    mean = aggregate_rows({"row": np.asarray(values, dtype=float)[:, None]})["row"].mean
    return f"{mean.value:.3f} ({mean.low:.3f}-{mean.high:.3f})"


def planner_lines() -> list[str]:
    lines = [
        "## The two planners on the depth map",
        "",
        "| views | speed | family | " + " | ".join(words for _, words in PLANNERS) + " |",
        "|---|---|---|" + "---|" * len(PLANNERS),
    ]
    for views in (3, 2, 1):
        for speed in SPEEDS:
            found = [RUNS / f"{stem}-{views_suffix(views)}-{speed}.json" for stem, _ in PLANNERS]
            if not all(path.exists() for path in found):
                continue
            loaded = [rows(path) for path in found]
            for family in FAMILIES:
                cells = " | ".join(rates(planner[family]) for planner in loaded)
                lines.append(f"| {views} | {speed_of(speed)} | {family} | {cells} |")
    return lines


def seed_table() -> list[str]:
    lines = [
        "## The residuals over training seeds",
        "",
        "Success and collision rate, mean over training seeds (rliable's 95% stratified-",
        "bootstrap interval); per seed in the last column (success / collisions), the shipped",
        "seed 5 first. The hybrid planning to where the target is was committed until",
        "session 44; the hybrid meeting the target is `--depth-hybrid` since.",
        "",
        "| views | speed | family | row | seeds | success | collisions | per seed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for views in (3, 2, 1):
        for speed in SPEEDS:
            for family in FAMILIES:
                for stem, words in (ALONE, HYBRID_STALE, HYBRID_TRACK):
                    runs = seed_files(stem, views, speed)
                    if not runs:
                        continue
                    scored = [rows(path)[family] for _, path in runs]
                    success = [row["success_rate"] for row in scored]
                    collisions = [row["collision_rate"] for row in scored]
                    each = ", ".join(
                        f"{seed}: {rates(row)}" for (seed, _), row in zip(runs, scored, strict=True)
                    )
                    lines.append(
                        f"| {views} | {speed_of(speed)} | {family} | {words} | {len(runs)} "
                        f"| {over_seeds(success)} | {over_seeds(collisions)} | {each} |"
                    )
    return lines


def paired_line(views: int, speed: str, family: str, words: str, row: dict, planner: dict):
    """One table line: `row` against the planner's row on the same tasks."""
    solved, planned = np.asarray(row["task_success"]), np.asarray(planner["task_success"])
    pair = paired_count(solved, planned)
    both = solved & planned

    def median_steps(of: dict) -> float:
        return float(np.median(np.asarray(of["task_steps"])[both])) if both.any() else np.nan

    return (
        f"| {views} | {speed_of(speed)} | {family} | {words} | {rates(row)} | {rates(planner)} "
        f"| {pair.first_only} / {pair.second_only} ({pair.p_value:.2g}) "
        f"| {median_steps(row):.0f} / {median_steps(planner):.0f} |"
    )


def real_time_line(views: int, family: str, words: str, before: Path, now: Path) -> str:
    """A row without and with `--real-time`."""
    before_row, now_row = rows(before)[family], rows(now)[family]

    def median_steps(row: dict) -> float:
        steps = np.asarray(row["task_steps"])[np.asarray(row["task_success"])]
        return float(np.median(steps)) if len(steps) else np.nan

    return (
        f"| {views} | {family} | {words} | {rates(before_row)} | {rates(now_row)} "
        f"| {np.mean(now_row['task_held_steps']):.1f} "
        f"| {median_steps(before_row):.0f} / {median_steps(now_row):.0f} |"
    )


def real_time_seed_table() -> list[str]:
    """The hybrid (its planner meeting the target and expecting its latency) in real time at
    0.2 m/s over training seeds (`moving/realtime_seeds.sh`, the shipped seed's row first)."""
    lines = [
        "### The hybrid over training seeds, in real time at 0.2 m/s",
        "",
        "| views | family | seeds | success | collisions | held steps a task | per seed |",
        "|---|---|---|---|---|---|---|",
    ]
    for views in (3, 2, 1):
        suffix = views_suffix(views)
        runs = [(SHIPPED_SEED, RUNS / "realtime" / f"hybrid-track-latency-{suffix}-0p2.json")]
        runs += [
            (
                seed,
                RUNS / "realtime" / "seeds" / f"hybrid-track-latency-{suffix}-seed{seed}-0p2.json",
            )
            for seed in SEEDS[views]
        ]
        runs = [(seed, path) for seed, path in runs if path.exists()]
        if not runs:
            continue
        for family in FAMILIES:
            scored = [rows(path)[family] for _, path in runs]
            held = np.mean([np.mean(row["task_held_steps"]) for row in scored])
            each = ", ".join(
                f"{seed}: {rates(row)}" for (seed, _), row in zip(runs, scored, strict=True)
            )
            lines.append(
                f"| {views} | {family} | {len(runs)} "
                f"| {over_seeds([row['success_rate'] for row in scored])} "
                f"| {over_seeds([row['collision_rate'] for row in scored])} | {held:.1f} | {each} |"
            )
    return lines


def real_time_table() -> list[str]:
    header = [
        "| views | family | row | as in the paper (acting takes no time) | real time "
        "| held steps a task | median steps of successes, without / with |",
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    lines = [
        "## Acting in real time",
        "",
        "`--real-time`: an act longer than the 50 ms control period holds the arm still a",
        "step per period it took (the held steps depend on the machine's speed). Success /",
        "collision rate without and with it; with it, the held steps per task (mean) and the",
        "median steps of the successes.",
        "",
        "### The target moving at 0.2 m/s",
        "",
        *header,
    ]
    for views in (3, 2, 1):
        for family in FAMILIES:
            for stem, words in REAL_TIME:
                name = f"{stem}-{views_suffix(views)}-0p2.json"
                if (RUNS / "realtime" / name).exists():
                    now = RUNS / "realtime" / name
                    before = RUNS / name.replace("-latency", "")
                    lines.append(real_time_line(views, family, words, before, now))
    lines += ["", *real_time_seed_table()]
    lines += ["", "### Static targets (without it: `arrival/`, Table 2's rows re-run)", "", *header]
    for views in (3, 2, 1):
        for family in FAMILIES:
            for stem, (words, table2) in STATIC.items():
                now = RUNS / "realtime" / f"{stem}-{views_suffix(views)}-0.json"
                if now.exists():
                    before = ARRIVAL / table2.format(views_suffix(views))
                    lines.append(real_time_line(views, family, words, before, now))
    return lines


def paired_table(planner_stem: str, planner_words: str) -> list[str]:
    lines = [
        f"## The shipped residuals task by task against the planner {planner_words}",
        "",
        "| views | speed | family | row | row | planner "
        "| only row / only planner (P) | median steps, row / planner |",
        "|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for views in (3, 2, 1):
        for speed in SPEEDS:
            planner_path = RUNS / f"{planner_stem}-{views_suffix(views)}-{speed}.json"
            if not planner_path.exists():
                print(f"missing {planner_path.name}: not run yet")
                continue
            planner = rows(planner_path)
            for family in FAMILIES:
                for stem, words in PAIRS_AGAINST[planner_stem]:
                    path = RUNS / f"{stem}-{views_suffix(views)}-{speed}.json"
                    if path.exists():
                        row = rows(path)[family]
                        lines.append(paired_line(views, speed, family, words, row, planner[family]))
    return lines


def main() -> None:
    lines = [
        "# A moving target on the test tasks: the residuals against RRT on the depth map",
        "",
        "Written by `python results/stage2/shield/moving_test.py` from `moving/*.json`",
        "(`moving/run.sh`, `moving/seeds.sh`); Table 2 test tasks, 200 per family, the target",
        "moving at the speed given (m/s). Success / collision rate unless said otherwise.",
        "",
        *planner_lines(),
        "",
        *seed_table(),
        "",
        *real_time_table(),
        "",
    ]
    for stem, words in reversed(PLANNERS):
        lines += [*paired_table(stem, words), ""]
    write_markdown(lines[:-1], HERE / "moving_test.md")


if __name__ == "__main__":
    main()
