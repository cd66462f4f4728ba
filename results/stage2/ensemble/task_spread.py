"""Do the 3-view students fail the same blocked tasks? (session 55; a description, nothing
chosen on it.)

Every 3-view student evaluated alone on a validation block (`ensemble.py --offset O --out
ensemble_O.jsonl`; seeds of the shipped recipe's regression and every lever's student since
session 33) ran the same 300 blocked tasks. Per task, how many of them solve it and how many
collide on it: if the failures were a set of tasks no student solves, what limits them would
be the tasks (or the teacher); if each student fails other tasks, it is how each one acts near
the obstacles. Also the majority vote per task (not a policy: it reads the outcomes) and, for
one student, where its failures lie in that count.

    python results/stage2/ensemble/task_spread.py [--block ensemble_350000.jsonl]
        [--student 3v-prev4-s7]
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np
from ensemble import STUDENTS  # (this directory: the script's own)

HERE = Path(__file__).resolve().parent
LEFT_OUT = 4
"""The spread is also printed without this many lowest students (on block 350000: the four
settings that clearly lost, centre crops twice and weight decay 1 and 0.1)."""
BINS = 6
"""The histograms' bins of student counts above 0 (inclusive ranges of about equal width)."""


def outcomes(block: Path) -> dict[str, dict]:
    """The blocked-family records of the 3-view students alone on `block`, by name."""
    records = {}
    for line in block.read_text().splitlines():
        record = json.loads(line)
        name = record["policy"]
        if record["family"] == "blocked" and name in STUDENTS and name.startswith("3v-"):
            records[name] = record
    return records


def bins(count: int) -> list[tuple[int, int]]:
    """(0, 0), then `BINS` ranges splitting 1..`count`."""
    edges = np.unique(np.linspace(0, count, BINS + 1).round().astype(int))
    return [(0, 0), *((lo + 1, hi) for lo, hi in itertools.pairwise(edges))]


def histogram(per_task: np.ndarray, count: int) -> str:
    return ", ".join(
        f"{lo}-{hi}: {((per_task >= lo) & (per_task <= hi)).sum()}"
        if lo != hi
        else f"{lo}: {(per_task == lo).sum()}"
        for lo, hi in bins(count)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--block", type=Path, default=HERE / "ensemble_350000.jsonl")
    parser.add_argument("--student", default="3v-prev4-s7")
    args = parser.parse_args()
    records = outcomes(args.block)
    if len(records) < 2:
        parser.error(f"{args.block}: fewer than two 3-view students alone on its blocked tasks")
    seeds = next(iter(records.values()))["seeds"]
    if any(record["seeds"] != seeds for record in records.values()):
        parser.error(f"{args.block}: the students ran different tasks")
    names = sorted(records)
    success = np.array([records[name]["success"] for name in names], dtype=int)
    collided = np.array([records[name]["collided"] for name in names], dtype=int)
    count, tasks = success.shape
    solved, collisions = success.sum(0), collided.sum(0)
    rates = success.mean(1)
    print(f"{args.block.name}: {count} 3-view students alone, {tasks} blocked tasks")
    print(f"students' success {rates.min():.3f}-{rates.max():.3f} (median {np.median(rates):.3f})")
    counts = success.sum(1)
    order = np.argsort(-counts, kind="stable")
    print("blocked tasks solved: " + ", ".join(f"{names[i]} {counts[i]}" for i in order))
    top = counts[order[: max(2, count - LEFT_OUT)]]
    print(
        f"the {len(top)} highest: {top.min()}-{top.max()}, mean {top.mean():.1f}, "
        f"standard deviation {top.std(ddof=1):.1f}"
    )
    print(f"tasks by how many students solve them: {histogram(solved, count)}")
    print(f"tasks by how many students collide on them: {histogram(collisions, count)}")
    print(
        f"solved by at least one: {(solved > 0).sum()}; by every one: {(solved == count).sum()}; "
        f"by a majority (the vote, reading outcomes): {(solved > count / 2).sum()}"
    )
    print(
        f"collided on by at least one: {(collisions > 0).sum()}; by half or more: "
        f"{(collisions >= count / 2).sum()}"
    )
    if args.student in records:
        mine = names.index(args.student)
        others = np.delete(success, mine, axis=0).sum(0)
        failed = success[mine] == 0
        half = (count - 1) / 2
        print(
            f"{args.student}: {failed.sum()} failures; on {(failed & (others > half)).sum()} of "
            f"them more than half of the other {count - 1} students succeed, on "
            f"{(failed & (others == 0)).sum()} none does; of its "
            f"{collided[mine].sum()} collisions, {(collided[mine] & (others > half)).sum()} on "
            "tasks more than half of the others solve"
        )


if __name__ == "__main__":
    main()
