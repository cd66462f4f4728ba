"""A moving target on the test tasks: the shipped residuals alone and in their hybrids against
RRT on the depth map (session 43; protocol in README.md, "A moving target on the test tasks").

    python results/stage2/shield/moving_test.py

Reads `moving/<row>-<views>-<speed>.json` (`moving/run.sh`) and writes `moving_test.md`
beside this file: per number of views, target speed and family, each row's success and
collision rate; the tasks only the row solves / only the depth-map planner (exact two-sided
sign test); and on the tasks both solve, the median steps of each.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from base_control import rows, write_markdown  # (this directory: the script's own)

from clamgen.experiments.policies import views_suffix
from clamgen.experiments.tables import paired_count

HERE = Path(__file__).resolve().parent
RUNS = HERE / "moving"
SPEEDS = ("0p1", "0p2")
"""The target speeds run, as the files spell them (0.1 and 0.2 m/s)."""
PAIRS = (("residual", "the residual alone"), ("hybrid", "the residual in its hybrid"))


def line(views: int, speed: str, family: str, words: str, row: dict, planner: dict) -> str:
    """One table line: `row` against the depth-map planner's row on the same tasks."""
    solved, planned = np.asarray(row["task_success"]), np.asarray(planner["task_success"])
    pair = paired_count(solved, planned)
    both = solved & planned

    def median_steps(of: dict) -> float:
        return float(np.median(np.asarray(of["task_steps"])[both])) if both.any() else np.nan

    steps, planner_steps = median_steps(row), median_steps(planner)
    return (
        f"| {views} | {speed.replace('p', '.')} | {family} | {words} "
        f"| {row['success_rate']:.3f} / {row['collision_rate']:.3f} "
        f"| {planner['success_rate']:.3f} / {planner['collision_rate']:.3f} "
        f"| {pair.first_only} / {pair.second_only} ({pair.p_value:.2g}) "
        f"| {steps:.0f} / {planner_steps:.0f} |"
    )


def main() -> None:
    lines = [
        "# A moving target on the test tasks: the residuals against RRT on the depth map",
        "",
        "Written by `python results/stage2/shield/moving_test.py` from `moving/*.json`",
        "(`moving/run.sh`); Table 2 test tasks, 200 per family, the target moving at the",
        "speed given (m/s). Success / collision rate of the row and of the depth-map planner",
        "of the same views; the tasks only the row solves / only the planner (exact two-sided",
        "sign test); median steps of each on the tasks both solve.",
        "",
        "| views | speed | family | row | row | RRT on the depth map "
        "| only row / only planner (P) | median steps, row / planner |",
        "|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for views in (3, 2, 1):
        for speed in SPEEDS:
            planner_path = RUNS / f"depth-rrt-{views_suffix(views)}-{speed}.json"
            if not planner_path.exists():
                print(f"missing {planner_path.name}: not run yet")
                continue
            planner = rows(planner_path)
            for family in ("obstacles", "blocked"):
                for stem, words in PAIRS:
                    path = RUNS / f"{stem}-{views_suffix(views)}-{speed}.json"
                    if path.exists():
                        row = rows(path)[family]
                        lines.append(line(views, speed, family, words, row, planner[family]))
    write_markdown(lines, HERE / "moving_test.md")


if __name__ == "__main__":
    main()
