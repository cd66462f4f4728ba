"""The depth shield, and the shield with the planner, on the three training seeds of the
shipped `residual-3views` recipe: seed 0 is the shipped policy
(results/table2/shielded_residual-3views.json, planned_residual-3views.json), seeds 1 and 2
the lookahead-fixed sweep's runs (fixed3_seed*_shielded.json, fixed3_seed*_planned.json here).
Mean success and mean collision rate per task family with rliable's 95% stratified-bootstrap
intervals, and each seed's values:

    python results/stage2/shield/three_seeds.py
"""

from __future__ import annotations

from pathlib import Path

from clamgen.experiments.aggregate import row_scores, seed_lines

HERE = Path(__file__).resolve().parent
TABLE2 = HERE.parents[1] / "table2"
FAMILIES = ("obstacles", "blocked")
VARIANTS = {
    "depth shield": ("shielded_residual-3views.json", "fixed3_seed{}_shielded.json"),
    "depth shield + planner when stuck": (
        "planned_residual-3views.json",
        "fixed3_seed{}_planned.json",
    ),
}


def main() -> None:
    for variant, (shipped, other) in VARIANTS.items():
        seeds = [row_scores(TABLE2 / shipped)] + [
            row_scores(HERE / other.format(s)) for s in (1, 2)
        ]
        print(f"{variant} (3 seeds: 0 shipped, 1, 2)")
        print("\n".join(seed_lines(seeds, FAMILIES)))


if __name__ == "__main__":
    main()
