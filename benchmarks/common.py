"""Shared helpers for the benchmarks: timing and CSV output."""

from __future__ import annotations

import csv
import platform
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


def machine() -> str:
    """The architecture and the vector instructions torch uses on this CPU, and whether it
    computes bf16 in hardware (the shipped policies' convs run in bf16 only there)."""
    import torch

    from clamgen.agents.encoders import native_bf16

    bf16 = "bf16 in hardware" if native_bf16("cpu") else "no bf16 in hardware"
    return f"{platform.machine()} {torch.backends.cpu.get_cpu_capability()}, {bf16}"


def write_csv(name: str, rows: list[dict]) -> Path:
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.csv"
    this_machine = machine()
    for row in rows:
        row.setdefault("machine", this_machine)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path
