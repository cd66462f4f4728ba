"""The noisy-depth rows (`run.sh`, `run_told.sh`) beside the exact-depth rows, as noise.md.

    python results/stage2/noise/noise.py

Per number of views and row: blocked success with its 95% Wilson interval, blocked
collisions and standard success at each noise level K (sd K z^2 m), exact depth (K = 0)
from the committed Table 2 rows of the same settings.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

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


def main() -> None:
    found: dict[tuple[str, str], dict[str, dict]] = {}
    levels = set()
    for path in sorted(HERE.glob("*.json")):
        match = re.fullmatch(r"(.+)-(3views|2views|1view)-k(.+)", path.stem)
        if match:
            row, views, level = match.groups()
            level = level.replace("p", ".")
            levels.add(level)
            found[(row, views, level)] = _families(path)
    levels = sorted(levels, key=float)
    lines = [
        "# Noisy depth: Table 2 test tasks",
        "",
        "Written by `python results/stage2/noise/noise.py` from the rows of `run.sh` and",
        "`run_told.sh` (README.md). Each cell: blocked success (95% Wilson interval) / blocked",
        "collisions / standard success, 200 + 200 test tasks, the shipped seed. K: the depth",
        "noise's sd is K z^2 m at depth z; K = 0 is exact depth (the committed rows).",
        "",
    ]
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
    (HERE / "noise.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
