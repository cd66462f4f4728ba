"""Shared helpers for the benchmarks: timing and CSV output."""

from __future__ import annotations

import csv
import time
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent.parent / "results" / "benchmarks"


def best_rate(fn, num_items: int, repeats: int = 3) -> float:
    """Items per second of `fn()` (which processes `num_items`), best of `repeats` runs."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return num_items / best


def write_csv(name: str, rows: list[dict]) -> Path:
    # Imported here: `update_cost.py --baseline-rev` runs this file's importers on an older
    # src/ that has no `machine` module, and only the parent process writes the CSV.
    from clamgen.experiments.machine import describe

    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.csv"
    this_machine = describe()
    for row in rows:
        row.setdefault("machine", this_machine)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path
