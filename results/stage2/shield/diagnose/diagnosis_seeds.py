"""The validation seeds a diagnosis script runs on (imported by the scripts beside it)."""

from __future__ import annotations

import json
from pathlib import Path

from clamgen.experiments.config import VALIDATION_SEEDS


def validation_seeds(num_tasks: int, offset: int, seeds_from: Path | None = None) -> list[int]:
    """The seeds of `seeds_from` (JSON lines with a `seed` each; sorted, once each), or else
    `num_tasks` seeds from `offset` into the validation range."""
    if seeds_from:
        lines = seeds_from.read_text().splitlines()
        return sorted({int(json.loads(line)["seed"]) for line in lines if line.strip()})
    return [int(s) for s in VALIDATION_SEEDS.seeds(num_tasks, VALIDATION_SEEDS.start + offset)]
