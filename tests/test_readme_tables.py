"""The README's Table 2 and the full one (results/table2/README.md) are copies of committed
results: every line of them is the line that `clamgen.experiments.tables.table2_markdown`
writes for that row from a committed Table 2 JSON under results/ (so a number in either cannot
drift from its file)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clamgen.experiments.tables import ObstacleRow, table2_markdown

ROOT = Path(__file__).resolve().parents[1]
TABLES = {
    "README.md": "### Table 2: obstacles, on the standard and the blocked-path tasks",
    "results/table2/README.md": (
        "# Table 2, every row: obstacles, on the standard and the blocked-path tasks"
    ),
}
"""Each file with a Table 2, and the heading its table follows."""


def _row_name(line: str) -> str:
    return line[2:].split(" | ")[0]


def committed_lines() -> dict[str, set[str]]:
    """Every Table 2 line the committed result files give, by row name."""
    lines: dict[str, set[str]] = {}
    for path in sorted((ROOT / "results").rglob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError):
            continue
        rows = data.get("rows") if isinstance(data, dict) else None
        if not rows or not isinstance(rows, list) or "collision_rate" not in rows[0]:
            continue  # not a Table 2 result
        for line in table2_markdown([ObstacleRow(**row) for row in rows]).splitlines()[2:]:
            lines.setdefault(_row_name(line), set()).add(line)
    return lines


def readme_table2(path: str = "README.md") -> list[str]:
    """The lines of the first table after `path`'s Table 2 heading."""
    text = (ROOT / path).read_text().splitlines()
    start = text.index(TABLES[path])
    header = next(i for i in range(start, len(text)) if text[i].startswith("| row |"))
    table = []
    for line in text[header + 2 :]:
        if not line.startswith("|"):
            break
        table.append(line)
    return table


@pytest.mark.parametrize("path", TABLES)
def test_table2_rows_come_from_committed_results(path):
    lines = readme_table2(path)
    assert len(lines) > 20
    committed = committed_lines()
    drifted = [line for line in lines if line not in committed.get(_row_name(line), set())]
    assert not drifted, f"{path} Table 2 rows that no committed JSON gives:\n" + "\n".join(drifted)


def test_the_readme_table2_is_a_selection_of_the_full_one():
    full = set(readme_table2("results/table2/README.md"))
    assert set(readme_table2()) <= full
    assert len(full) > len(readme_table2())


@pytest.mark.parametrize(
    "name",
    [
        "RRT with full model",
        "IK interpolation (no obstacle model)",
        *(
            f"RRT on the depth map of {v}, no learned policy (ours)"
            for v in ("3 RGBD views", "1 RGBD view")
        ),
    ],
)
def test_baseline_rows_are_in_the_readme(name):
    assert name in {_row_name(line) for line in readme_table2()}


def test_readme_aims_table_is_the_committed_results(results_script):
    aims = results_script("stage2/ensemble/shipped_seeds.py").aims_table()
    committed = (ROOT / "results" / "stage2" / "ensemble" / "aims.md").read_text()
    assert committed == aims + "\n"
    assert aims in (ROOT / "README.md").read_text()
