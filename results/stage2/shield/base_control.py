"""What the vision residual adds inside the depth wrappers: the residual's base (no vision)
through the same wrappers, against the shipped residual, on the same test tasks (session 42;
protocol in README.md, "Session 42").

    python results/stage2/shield/base_control.py

Reads the committed Table 2 files (`results/table2/`): the shipped residual of each number of
views (seed 5) alone and through each wrapper, the base alone and through the same wrappers
(`clamgen eval --table 2 --policy base --depth-views V ...`), where it was run no policy
inside the wrapper (`hold_control.py`), and where it was run obstacle-blind IK interpolation
through the same wrapper (`ik_control.sh`, session 48). Writes
`base_control.md` beside this file: per wrapper and task family, each row's success,
collision rate and act times, and task by task how many tasks only the residual's row solves
and how many only the base's (and only IK interpolation's), with the exact two-sided sign
test on those.
"""

from __future__ import annotations

import json
from pathlib import Path

from clamgen.experiments.tables import paired_count

HERE = Path(__file__).resolve().parent
TABLE2 = HERE.parents[2] / "results" / "table2"
ENSEMBLE = HERE.parent / "ensemble"
VIEWS = {3: "3views", 2: "2views", 1: "1view"}
PAIRS = [
    *((views, "alone", ENSEMBLE / f"{views}v-dagger+2_test.json", TABLE2 / "base.json")
      for views in VIEWS),
    *(
        (views, wrapper, TABLE2 / f"{wrapper}_residual-{suffix}.json",
         TABLE2 / f"base_through_{wrapper.removesuffix('_fine')}_{suffix}.json")
        for wrapper in ("shielded_fine", "hybrid", "escapes")
        for views, suffix in VIEWS.items()
    ),
    (1, "escapes_planner", TABLE2 / "escapes_planner_residual-1view.json",
     TABLE2 / "base_through_escapes_planner_1view.json"),
]  # fmt: skip
"""(views, how it acts, the shipped residual's row file, the base's row file)."""
WORDS = {
    "alone": "alone",
    "shielded_fine": "the hybrid's shield alone (no planner, no escapes)",
    "hybrid": "the hybrid (shield + planner when stuck)",
    "escapes": "shield + random escapes when stuck",
    "escapes_planner": "shield + planner when stuck + escapes where it finds no path",
}


def rows(path: Path) -> dict[str, dict]:
    return {row["family"]: row for row in json.loads(path.read_text())["rows"]}


def write_markdown(lines: list[str], out: Path) -> None:
    """Write `lines` as the Markdown file `out`, and print them."""
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print("wrote", out)


def cell(row: dict) -> str:
    text = f"{row['success_rate']:.3f} / {row['collision_rate']:.3f} / {row['median_act_ms']:.2f}"
    return text + (f" (p99 {row['act_p99_ms']:.1f})" if "act_p99_ms" in row else "")


def control(base_path: Path, kind: str) -> dict[str, dict] | None:
    """The rows of the control `kind` ("hold", "ik") beside the base's row file, if run; acting
    alone, IK interpolation's own Table 2 row (`ik.json`), and no row for holding still."""
    if not base_path.name.startswith("base_through_"):
        path = base_path.with_name(f"{kind}.json") if kind == "ik" else None
    else:
        path = base_path.with_name(base_path.name.replace("base_through_", f"{kind}_through_"))
    return rows(path) if path is not None and path.exists() else None


def paired(first: dict, second: dict) -> str:
    pair = paired_count(first["task_success"], second["task_success"])
    return f"{pair.first_only} / {pair.second_only} ({pair.p_value:.2g})"


def main() -> None:
    lines = [
        "# The residual's base (no vision) through the same depth wrappers (session 42)",
        "",
        "Written by `python results/stage2/shield/base_control.py` from the Table 2 files it",
        "names; test tasks, 200 per family, the shipped residuals (seed 5) and the base",
        "(`clamgen eval --table 2 --policy base --depth-views V ...`). Each cell: success /",
        "collision rate / median act ms (99th percentile). Task by task: tasks only the",
        "residual's row solves / only the base's, and the exact two-sided sign test on them.",
        "",
        "The column \"no policy\", where it was run (`hold_control.py`): the arm holding still",
        "inside the wrapper, so the wrapper alone acts. The last two, where they were run",
        "(`ik_control.sh`, session 48): obstacle-blind IK interpolation (no vision, no",
        "learning) as the policy inside the same wrapper, and the tasks only the residual's /",
        "only IK interpolation's row solves.",
        "",
        "| views | acting | family | shipped residual | base (no vision) "
        "| only residual / only base (P) | no policy | IK interpolation "
        "| only residual / only IK (P) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for views, how, residual_path, base_path in PAIRS:
        if not base_path.exists():
            print(f"missing {base_path.name}: not run yet")
            continue
        residual, base = rows(residual_path), rows(base_path)
        hold, ik = control(base_path, "hold"), control(base_path, "ik")
        for family in ("obstacles", "blocked"):
            mine = residual[family]
            lines.append(
                f"| {views} | {WORDS[how]} | {family} | {cell(mine)} | {cell(base[family])} | "
                f"{paired(mine, base[family])} | {cell(hold[family]) if hold else '-'} | "
                f"{cell(ik[family]) if ik else '-'} | {paired(mine, ik[family]) if ik else '-'} |"
            )
    write_markdown(lines, HERE / "base_control.md")


if __name__ == "__main__":
    main()
