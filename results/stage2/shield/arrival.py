"""How fast each arrives: the shipped residuals alone and in their hybrids against RRT on the
depth map, on the tasks both solve (session 43; protocol in README.md, "How fast each
arrives").

    python results/stage2/shield/arrival.py

Reads `arrival/<row>-<views>.json` (`arrival/run.sh`: Table 2 rows that record each task's
steps and tip path) and writes `arrival.md` beside this file: per number of views, family and
pair, each row's success, the tasks both solve, the median steps and tip path (m) of each on
them, and the tasks where each arrives in fewer steps, with the exact two-sided sign test.
The README's Table 2 rows of the residuals stay as committed; this file's success columns are
these re-runs' (they may differ on a few tasks: the committed rows' convs ran in float32 on
another CPU, and the plans have a time budget).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from base_control import rows, write_markdown  # (this directory: the script's own)

from clamgen.experiments.policies import views_suffix
from clamgen.experiments.tables import paired_count

HERE = Path(__file__).resolve().parent
RUNS = HERE / "arrival"
PAIRS = (("residual", "the residual alone"), ("hybrid", "the residual in its hybrid"))
"""The rows set against the depth-map baseline (`depth-rrt`), by file stem."""


def compare(row: dict, baseline: dict) -> str:
    """One table line's cells after the pair's names: `row` against the depth-map baseline."""
    both = np.asarray(row["task_success"]) & np.asarray(baseline["task_success"])
    steps = np.asarray(row["task_steps"])[both], np.asarray(baseline["task_steps"])[both]
    paths = np.asarray(row["task_tip_path_m"])[both], np.asarray(baseline["task_tip_path_m"])[both]
    faster = paired_count(steps[0] < steps[1], steps[1] < steps[0])
    return (
        f"{row['success_rate']:.3f} / {baseline['success_rate']:.3f} | {int(both.sum())} "
        f"| {np.median(steps[0]):.0f} / {np.median(steps[1]):.0f} "
        f"| {np.median(paths[0]):.2f} / {np.median(paths[1]):.2f} "
        f"| {faster.first_only} / {faster.second_only} ({faster.p_value:.2g})"
    )


def main() -> None:
    lines = [
        "# How fast each arrives: the shipped residuals against RRT on the depth map",
        "",
        "Written by `python results/stage2/shield/arrival.py` from `arrival/*.json`",
        "(`arrival/run.sh`); Table 2 test tasks, 200 per family. On the tasks both rows solve:",
        "median steps (20 a second) and tip path of each, and the tasks where each arrives in",
        "fewer steps (exact two-sided sign test; ties left out).",
        "",
        "| views | family | row | success: row / RRT on the depth map | both solve "
        "| median steps | median tip path (m) | fewer steps: row / RRT on the depth map (P) |",
        "|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for views in (3, 2, 1):
        suffix = views_suffix(views)
        baseline_path = RUNS / f"depth-rrt-{suffix}.json"
        if not baseline_path.exists():
            print(f"missing {baseline_path.name}: not run yet")
            continue
        baseline = rows(baseline_path)
        for family in ("obstacles", "blocked"):
            for stem, words in PAIRS:
                path = RUNS / f"{stem}-{suffix}.json"
                if path.exists():
                    cells = compare(rows(path)[family], baseline[family])
                    lines.append(f"| {views} | {family} | {words} | {cells} |")
    write_markdown(lines, HERE / "arrival.md")


if __name__ == "__main__":
    main()
