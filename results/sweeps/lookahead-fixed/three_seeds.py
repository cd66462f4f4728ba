"""The shipped `residual-3views` recipe over three training seeds: seed 0 is the shipped run
(results/table2/distilled_fixed_3views.json; its iteration chosen on 300 validation tasks),
seeds 1 and 2 the sweep's runs (summary.json here; best of the 100 per-iteration validation
tasks). Mean success and mean collision rate per task family with rliable's 95%
stratified-bootstrap intervals, and each seed's values:

    python results/sweeps/lookahead-fixed/three_seeds.py
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from clamgen.experiments.aggregate import seed_lines

HERE = Path(__file__).resolve().parent
SHIPPED = HERE.parents[1] / "table2" / "distilled_fixed_3views.json"
FAMILIES = ("obstacles", "blocked")


def _seed0() -> tuple[dict[str, float], dict[str, float]]:
    rows = json.loads(SHIPPED.read_text())["rows"]
    success = {r.get("family", "obstacles"): r["success_rate"] for r in rows}
    collision = {r.get("family", "obstacles"): r["collision_rate"] for r in rows}
    return success, collision


def _collision_from_table(path: Path) -> dict[str, float]:
    """The 'collision rate, standard / blocked' cell of a sweep run's committed eval table."""
    row = path.read_text().splitlines()[2].split("|")
    standard, blocked = (float(x) for x in re.findall(r"\d\.\d+", row[5]))
    return {"obstacles": standard, "blocked": blocked}


def main() -> None:
    summary = json.loads((HERE / "summary.json").read_text())
    success, collision = _seed0()
    seeds = {0: (success, collision)}
    for run in summary["runs"]:
        scores = run["test"]["scores"]
        seeds[run["seed"]] = (scores, _collision_from_table(HERE / f"seed{run['seed']}-table2.md"))
    print(f"{len(seeds)} seeds: {sorted(seeds)}")
    runs = [{f: (seeds[s][0][f], seeds[s][1][f]) for f in FAMILIES} for s in sorted(seeds)]
    print("\n".join(line.removeprefix("  ") for line in seed_lines(runs, FAMILIES)))


if __name__ == "__main__":
    main()
