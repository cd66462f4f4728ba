"""Where the 3-view students fail on the yardstick block (session 52; a description of
committed lines, nothing chosen on it).

Block 350000's 300 blocked validation tasks (the block every 3-view lever since session 33 was
read on) split by the best true clearance of their goal's IK solutions (`../shield/
goal_clearance.py`'s measure; written once to `block_strata_350000.json`), and each 3-view
student's blocked successes and collisions in `ensemble_350000.jsonl` per stratum: how much of
the gap to the 0.90 aim lies on goals that no configuration reaches with 1 cm to spare (on the
test tasks, 16 of 200; `../shield/goal_clearance.md`). Prints a Markdown table
(`block_strata_350000.md`).

    python results/stage2/ensemble/block_strata.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from clamgen.envs import ReachEnv

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "shield"))
from goal_clearance import best_clearance, strata  # noqa: E402 (the sibling script's)

LINES = HERE / "ensemble_350000.jsonl"
CACHE = HERE / "block_strata_350000.json"
OUT = HERE / "block_strata_350000.md"
STUDENTS = (
    "3v-reg-s7",
    "3v-reg-s8",
    "3v-reg-s9",
    "3v-wide32-s7",
    "3v-reg96k-s7",
    "3v-nodrop-s7",
    "3v-pool8-s7",
    "3v-least4-s7",
    "3v-prev4-s7",
    "3v-prev4-s8",
    "3v-tanh-prev4-s7",
)
"""The 3-view students alone scored on the block (the shipped recipe's regressions and the
levers on them), in the ledger's order."""


def blocked_lines() -> dict[str, dict]:
    """The latest blocked line of each student in `LINES`."""
    lines = {}
    for text in LINES.read_text().splitlines():
        line = json.loads(text)
        if line["family"] == "blocked" and line["policy"] in STUDENTS:
            lines[line["policy"]] = line
    return lines


def best_clearances(seeds: list[int]) -> np.ndarray:
    """Per task seed, the best true clearance (m) of its goal's IK solutions."""
    if CACHE.exists():
        cached = json.loads(CACHE.read_text())
        if cached["seeds"] == seeds:
            return np.asarray(cached["best_clearance_m"])
    env = ReachEnv(num_obstacles=2, task_family="blocked")
    best = [best_clearance(env, seed) for seed in seeds]
    CACHE.write_text(json.dumps({"seeds": seeds, "best_clearance_m": best}, indent=1))
    return np.asarray(best)


def student_row(name: str, line: dict, masks: list[np.ndarray]) -> str:
    """A student's table row: its blocked successes (collisions) in all and per stratum."""
    success = np.asarray(line["success"], bool)
    collided = np.asarray(line["collided"], bool)
    every = np.ones_like(success)
    cells = [f"{int(success[m].sum())} ({int(collided[m].sum())})" for m in (every, *masks)]
    return f"| {name} | " + " | ".join(cells) + " |"


def main() -> None:
    lines = blocked_lines()
    seeds = lines[STUDENTS[0]]["seeds"]
    if any(line["seeds"] != seeds for line in lines.values()):
        raise ValueError(f"{LINES}: the students were scored on different tasks")
    best = best_clearances(seeds)
    masks, header = strata(best)
    rows = [
        "Block 350000's blocked validation tasks by the best true clearance of the goal's IK "
        "solutions (`block_strata.py`); per student, successes (collisions) in each stratum.",
        "",
        f"| student | all {len(seeds)} | {header} |",
        "|---|---|" + "---|" * len(masks),
    ]
    rows += [student_row(name, lines[name], masks) for name in STUDENTS if name in lines]
    OUT.write_text("\n".join(rows) + "\n")
    print(OUT.read_text())


if __name__ == "__main__":
    main()
