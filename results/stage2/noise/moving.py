"""The told hybrids meeting a moving target with noisy depth, over training seeds (session 48).

    python results/stage2/noise/moving.py

Reads `moving/hybrid-told-<views>-k0p01-0p2[-seed<S>].json` (`moving.sh`; no suffix: the
shipped student, seed 5) and writes `moving/summary.txt`: per number of views, the mean over
seeds of blocked and standard success and collision rate with rliable's 95% stratified-bootstrap
interval, and each seed's value (`clamgen.experiments.aggregate.seed_summary`).
"""

from __future__ import annotations

import re
from pathlib import Path

from clamgen.experiments.aggregate import seed_summary

HERE = Path(__file__).resolve().parent / "moving"
SHIPPED_SEED = 5


def runs(views: str) -> list[tuple[int, Path]]:
    """(training seed, Table 2 JSON) of each evaluated student of `views`."""
    found = []
    for path in sorted(HERE.glob(f"hybrid-told-{views}-k0p01-0p2*.json")):
        match = re.search(r"-seed(\d+)\.json$", path.name)
        found.append((int(match.group(1)) if match else SHIPPED_SEED, path))
    return sorted(found)


def main() -> None:
    rows = {
        f"{views}: hybrid told the noise, K = 0.01, target at 0.2 m/s": runs(views)
        for views in ("3views", "2views", "1view")
    }
    text = seed_summary({name: found for name, found in rows.items() if found},
                        ("blocked", "obstacles"))  # fmt: skip
    (HERE / "summary.txt").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
