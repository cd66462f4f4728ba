"""RRT on the depth map with no learned policy, beside the policies on the same sensors
(session 43; protocol in README.md, "Session 43").

    python results/stage2/shield/depth_rrt_compare.py

Reads the committed Table 2 files: the `depth-rrt-*` baselines (`clamgen eval --table 2
--policy depth-rrt-<V>`), the shipped residual of each number of views (seed 5) alone and in
its hybrid, the held arm inside the hybrid (session 42, `hold_control.py`: the same planner
after a 10-step wait) and RRT with the full scene model. Writes `depth_rrt_compare.md` beside
this file: per number of views and task family, each row's success / collision rate / median
act ms (and the planning time's 95th percentile per task), and task by task how many tasks
only the baseline solves and how many only the other row, with the exact two-sided sign test.
"""

from __future__ import annotations

from pathlib import Path

from base_control import rows, write_markdown  # (this directory: the script's own)

from clamgen.experiments.policies import views_suffix
from clamgen.experiments.tables import paired_count

HERE = Path(__file__).resolve().parent
TABLE2 = HERE.parents[2] / "results" / "table2"
ENSEMBLE = HERE.parent / "ensemble"
OTHERS = {
    "shipped residual alone": lambda views: ENSEMBLE / f"{views}v-dagger+2_test.json",
    "shipped residual in its hybrid": lambda v: TABLE2 / f"hybrid_residual-{views_suffix(v)}.json",
    "held arm in the hybrid (plans after 10 steps)": lambda v: (
        TABLE2 / f"hold_through_hybrid_{views_suffix(v)}.json"
    ),
    "RRT with the full scene model": lambda views: TABLE2 / "rrt.json",
}
"""The rows set beside each baseline, by what acts: their Table 2 files by number of views."""


def cell(row: dict) -> str:
    text = f"{row['success_rate']:.3f} / {row['collision_rate']:.3f} / {row['median_act_ms']:.2f}"
    plan = row.get("plan_time_p95_s")
    return text + (f" (plans p95 {plan:.2f} s)" if plan else "")


def main() -> None:
    lines = [
        "# RRT on the depth map, no learned policy, beside the policies (session 43)",
        "",
        "Written by `python results/stage2/shield/depth_rrt_compare.py` from the Table 2 files",
        "it names; test tasks, 200 per family. Each cell: success / collision rate / median act",
        "ms (the planning time's 95th percentile per task). Task by task: tasks only the",
        "depth-map baseline solves / only the other row, and the exact two-sided sign test.",
        "",
        "| views | family | RRT on the depth map | beside it | that row "
        "| only baseline / only that row (P) |",
        "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for views in (3, 2, 1):
        path = TABLE2 / f"depth_rrt_{views_suffix(views)}.json"
        if not path.exists():
            print(f"missing {path.name}: not run yet")
            continue
        baseline = rows(path)
        for family in ("obstacles", "blocked"):
            for words, other_path in OTHERS.items():
                other = rows(other_path(views))[family]
                pair = paired_count(baseline[family]["task_success"], other["task_success"])
                lines.append(
                    f"| {views} | {family} | {cell(baseline[family])} | {words} | {cell(other)} "
                    f"| {pair.first_only} / {pair.second_only} ({pair.p_value:.2g}) |"
                )
    write_markdown(lines, HERE / "depth_rrt_compare.md")


if __name__ == "__main__":
    main()
