"""The README's Table 2 is a copy of committed results: every line of it is the line that
`clamgen.experiments.tables.table2_markdown` writes for that row from a committed Table 2
JSON under results/ (so a number in the README cannot drift from its file)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clamgen.experiments.tables import ObstacleRow, table2_markdown

ROOT = Path(__file__).resolve().parents[1]
HEADING = "### Table 2: obstacles, on the standard and the blocked-path tasks"


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


def readme_table2() -> list[str]:
    text = (ROOT / "README.md").read_text().splitlines()
    start = text.index(HEADING)
    header = next(i for i in range(start, len(text)) if text[i].startswith("| row |"))
    table = []
    for line in text[header + 2 :]:
        if not line.startswith("|"):
            break
        table.append(line)
    return table


def test_readme_table2_rows_come_from_committed_results():
    lines = readme_table2()
    assert len(lines) > 20
    committed = committed_lines()
    drifted = [line for line in lines if line not in committed.get(_row_name(line), set())]
    assert not drifted, "README Table 2 rows that no committed JSON gives:\n" + "\n".join(drifted)


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
