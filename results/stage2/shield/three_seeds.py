"""The depth shield, and the shield with the planner, on the three training seeds of the
shipped `residual-3views` recipe: seed 0 is the shipped policy
(results/table2/shielded_residual-3views.json, planned_residual-3views.json), seeds 1 and 2
the lookahead-fixed sweep's runs (fixed3_seed*_shielded.json, fixed3_seed*_planned.json here).
Mean success and mean collision rate per task family with rliable's 95% stratified-bootstrap
intervals, and each seed's values; writes the seed set `three_seeds.json` through which
`clamgen report` aggregates the two rows over the seeds:

    python results/stage2/shield/three_seeds.py
"""

from __future__ import annotations

from pathlib import Path

from clamgen.experiments.aggregate import seed_summary, table2_row_name, write_seed_set

HERE = Path(__file__).resolve().parent
TABLE2 = HERE.parents[1] / "table2"
FAMILIES = ("obstacles", "blocked")
VARIANTS = (
    ("shielded_residual-3views.json", "fixed3_seed{}_shielded.json"),  # depth shield
    ("planned_residual-3views.json", "fixed3_seed{}_planned.json"),  # + planner when stuck
)
"""The shipped policy's test row and its other seeds' (by seed), for each way of acting."""


def main() -> None:
    rows = {}
    for shipped, other in VARIANTS:
        files = [TABLE2 / shipped] + [HERE / other.format(s) for s in (1, 2)]
        rows[table2_row_name(files[0])] = list(zip((0, 1, 2), files, strict=True))
    print(seed_summary(rows, FAMILIES))
    command = "python results/stage2/shield/three_seeds.py"
    note = (
        "seed 0 is the policy shipped until session 24, seeds 1 and 2 the lookahead-fixed "
        "sweep's runs"
    )
    write_seed_set(rows, HERE / "three_seeds.json", command, note)


if __name__ == "__main__":
    main()
