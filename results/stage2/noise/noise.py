"""The noisy-depth rows (`run.sh`, `run_told.sh`) beside the exact-depth rows, as noise.md.

    python results/stage2/noise/noise.py

Per number of views and row: blocked success with its 95% Wilson interval, blocked
collisions and standard success at each noise level K (sd K z^2 m), exact depth (K = 0)
from the committed Table 2 rows of the same settings. Then the rows run on more training
seeds (`seeds.sh`, files `seeds/<kind><V>_seed<S>_k<K>.json`; the shipped seed's row from
above): means over seeds with 95% stratified-bootstrap intervals, beside the exact-depth rows
of the same seeds (`../ensemble/seeds/`). Last, the told rows as sessions 45-46 ran them, with
the map's target test a sphere (`sphere/`, the same layout), beside the rows above.
"""

from __future__ import annotations

import json
import re
import statistics
from pathlib import Path

from clamgen.experiments.aggregate import row_scores, seed_summary
from clamgen.experiments.tables import wilson_interval

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
VIEWS = {"3views": "3v", "2views": "2v", "1view": "1v"}
ROWS = {
    "residual": "the residual alone",
    "hybrid": "hybrid (as shipped)",
    "hybrid-told": "hybrid, map told the noise",
    "escapes": "escapes (as shipped)",
    "escapes-told": "escapes, map told the noise",
    "depth-rrt": "depth-map planner (as shipped)",
    "depth-rrt-told": "depth-map planner, map told the noise",
}
EXACT = {
    "residual": "results/stage2/ensemble/{v}-dagger+2_test.json",
    "hybrid": "results/table2/hybrid_residual-{views}.json",
    "escapes": "results/table2/escapes_residual-{views}.json",
    "depth-rrt": "results/table2/depth_rrt_{underscored}.json",
}
"""The committed exact-depth rows of the same settings (the told rows share them: told
nothing, a map assumes exact depth)."""


HYBRID_EXACT = ("../../table2/hybrid_residual-{views}.json", "seeds/hybrid{n}_seed{seed}.json")
SEED_KINDS = {
    "alone": ("the residual alone", "residual", "the residual alone",
              ("{v}v-dagger+2_test.json", "seeds/student{n}_seed{seed}.json")),
    "hybrid-told": (ROWS["hybrid-told"], "hybrid-told", ROWS["hybrid"], HYBRID_EXACT),
    "escapes-told": (ROWS["escapes-told"], "escapes-told", ROWS["escapes"],
                     ("../../table2/escapes_residual-{views}.json",
                      "seeds/escapes{n}_seed{seed}.json")),
    "hybrid-told64": ("hybrid on the policy's own views, map told the noise", None,
                      ROWS["hybrid"], HYBRID_EXACT),
}  # fmt: skip
"""`seeds.sh`'s kinds: (row name; the stem of the shipped seed's row above, None where
seeds/ holds it as seed 5; the exact-depth row's name; its files under `../ensemble/`, the
shipped seed's and another seed's: the same students on exact depth, the hybrids' the
committed hybrid, whose map nothing tells)."""
SHIPPED_SEED = 5
VIEWS_OF = {"3": "3views", "2": "2views", "1": "1view"}
ENSEMBLE = ROOT / "results" / "stage2" / "ensemble"


def seed_rows(folder: Path = HERE) -> dict[str, list[tuple[int, Path]]]:
    """{row: [(training seed, Table 2 JSON), ...]}, the shipped seed first, for every (kind,
    views, K) with rows in `folder`/seeds/, each followed by its exact-depth row on the same
    seeds."""
    runs: dict[tuple[str, str, str], list[tuple[int, Path]]] = {}
    kinds = "|".join(sorted(SEED_KINDS, key=len, reverse=True))
    for path in sorted((folder / "seeds").glob("*.json")):
        match = re.fullmatch(rf"({kinds})(\d)_seed(\d+)_k(.+)", path.stem)
        if match:
            kind, n, seed, level = match.groups()
            runs.setdefault((kind, n, level), []).append((int(seed), path))
    rows = {}
    for (kind, n, level), seeds in sorted(runs.items(), key=lambda item: -int(item[0][1])):
        views = VIEWS_OF[n]
        name, shipped, exact_name, (first, other) = SEED_KINDS[kind]
        seeds = sorted(seeds)
        if shipped is not None:
            seeds = [(SHIPPED_SEED, folder / f"{shipped}-{views}-k{level}.json"), *seeds]
        rows[f"{views}, {name}, K = {level.replace('p', '.')}"] = seeds
        rows[f"{views}, {exact_name}, exact depth, the seeds of: {name}"] = [
            (seed, ENSEMBLE / (first if seed == SHIPPED_SEED else other).format(
                v=n, n=n, views=views, seed=seed))
            for seed, _ in seeds
        ]  # fmt: skip
    return rows


def seed_table(rows: dict[str, list[tuple[int, Path]]]) -> list[str]:
    """Markdown: per number of views and kind, the means over seeds of blocked success and
    collisions on exact depth and at each K (the rows of `seed_rows`)."""
    levels = sorted({name.rsplit("K = ", 1)[1] for name in rows if "K = " in name}, key=float)
    lines = ["| views | row | seeds | exact depth | " + " | ".join(f"K = {k}" for k in levels)]
    lines[0] += " |"
    lines.append("|---" * (len(levels) + 4) + "|")
    for n, views in VIEWS_OF.items():
        for name, _, exact_name, _ in SEED_KINDS.values():
            noisy = [rows.get(f"{views}, {name}, K = {k}") for k in levels]
            exact = rows.get(f"{views}, {exact_name}, exact depth, the seeds of: {name}")
            if exact is None or not any(noisy):
                continue
            cells = [_seed_means(exact), *(_seed_means(runs) for runs in noisy)]
            lines.append(f"| {n} | {name} | {len(exact)} | " + " | ".join(cells) + " |")
    return lines


def _seed_means(runs: list[tuple[int, Path]] | None) -> str:
    """'success / collisions / act ms' on the blocked tasks: means over seeds, and the median
    over seeds of each row's median act."""
    if runs is None:
        return "-"
    scores = [row_scores(path)["blocked"] for _, path in runs]
    success, collided = (sum(s[i] for s in scores) / len(scores) for i in (0, 1))
    act = statistics.median(_families(path)["blocked"]["median_act_ms"] for _, path in runs)
    return f"{success:.3f} / {collided:.3f} / {act:.2f}"


def _families(path: Path) -> dict[str, dict]:
    return {row["family"]: row for row in json.loads(path.read_text())["rows"]}


def _cell(rows: dict[str, dict] | None) -> str:
    if rows is None:
        return "-"
    blocked, standard = rows["blocked"], rows["obstacles"]
    tasks = blocked["num_tasks"]
    low, high = wilson_interval(round(blocked["success_rate"] * tasks), tasks)
    return (
        f"{blocked['success_rate']:.3f} ({low:.2f}-{high:.2f}) / "
        f"{blocked['collision_rate']:.3f} / {standard['success_rate']:.3f}"
    )


def shipped_tables(folder: Path) -> list[str]:
    """Markdown: per number of views, the shipped seed's rows in `folder` (one cell per K,
    exact depth first)."""
    found: dict[tuple[str, str, str], dict[str, dict]] = {}
    levels = set()
    for path in sorted(folder.glob("*.json")):
        match = re.fullmatch(r"(.+)-(3views|2views|1view)-k(.+)", path.stem)
        if match:
            row, views, level = match.groups()
            level = level.replace("p", ".")
            levels.add(level)
            found[(row, views, level)] = _families(path)
    levels = sorted(levels, key=float)
    lines = []
    for views in VIEWS:
        present = [row for row in ROWS if any((row, views, k) in found for k in levels)]
        if not present:
            continue
        lines += [f"## {views}", ""]
        lines.append("| row | " + " | ".join(["K = 0 (exact)", *(f"K = {k}" for k in levels)]))
        lines[-1] += " |"
        lines.append("|---" * (len(levels) + 2) + "|")
        for row in present:
            base = row.removesuffix("-told")
            exact = EXACT[base].format(
                v=VIEWS[views], views=views, underscored=views.replace("-", "_")
            )
            cells = [_cell(_families(ROOT / exact))]
            cells += [_cell(found.get((row, views, k))) for k in levels]
            lines.append(f"| {ROWS[row]} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def main() -> None:
    lines = [
        "# Noisy depth: Table 2 test tasks",
        "",
        "Written by `python results/stage2/noise/noise.py` from the rows of `run.sh` and",
        "`run_told.sh` (README.md). Each cell: blocked success (95% Wilson interval) / blocked",
        "collisions / standard success, 200 + 200 test tasks, the shipped seed. K: the depth",
        "noise's sd is K z^2 m at depth z; K = 0 is exact depth (the committed rows).",
        "",
        *shipped_tables(HERE),
    ]
    lines += [
        "## Over training seeds",
        "",
        "The students of the shipped recipes' other seeds (`seeds.sh`), with the shipped seed's",
        "row above; per family the mean over seeds of success and collision rate with its 95%",
        "stratified-bootstrap interval (rliable), and each seed's value; beside each, the same",
        "seeds on exact depth (the wrappers as shipped: exact depth has no noise to tell). First",
        "blocked success / blocked collisions (means over seeds) / act ms (the median over seeds",
        "of each row's blocked median act; two evaluations at a time on the two cores):",
        "",
        *seed_table(seed_rows()),
        "",
        "```",
        seed_summary(seed_rows(), ("blocked", "obstacles")),
        "```",
        "",
        "# The told rows with the sphere target test (sessions 45-46)",
        "",
        "Before session 47 the told map took a point for target within a sphere 3 sds of the",
        "noise (at the target's depth) wider than its exact-depth filter; since, along the",
        "point's ray, like the arm's and the table's tests (README.md, pilots 1 and 5). The told",
        "rows as they ran then (`sphere/`), the same cells as above:",
        "",
        *(line.replace("## ", "### ") for line in shipped_tables(HERE / "sphere")),
        *seed_table(seed_rows(HERE / "sphere")),
        "",
    ]
    (HERE / "noise.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
