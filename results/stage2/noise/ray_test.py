"""Validation pilot (session 47): the told map's target test along each ray again, on a fresh
block, under a rule that weighs the collision aim.

Pilot 1 (`target_test.py`, block 490000, K = 0.01) compared the told map's target test, a
sphere grown by 3 sds of the noise at the target's depth (committed), with a test along each
pixel's ray (as the arm's and the table's tests run): summed over the 2- and 1-view hybrids
and planners, collisions fell from 38 to 6 of 400 blocked tasks and successes from 359 to 354.
Its rule allowed 4 successes lost and missed by one, so the sphere stayed. Over training
seeds on the test tasks the told rows at K = 0.01 miss the collision aim of 0.05 (the 3- and
2-view hybrids 0.064 / 0.052, the escapes 0.052 / 0.057 / 0.067) with success to spare for
the hybrids (0.935 / 0.948 / 0.932 against aims of 0.90 / 0.85 / 0.70). A rule that counts a
collision avoided against a success lost is the one the issue's aims ask for.

Protocol (written before any run): the shipped 3-, 2- and 1-view residuals in their hybrids
and with the escapes (`--depth-hybrid` / `--depth-escapes`), told the noise, K = 0.003 and
0.01, on 100 blocked and 50 standard validation tasks from offset 520000 (a block no earlier
check used), the same tasks for both tests, run side by side on the two cores: `--test
sphere` runs the committed code, `--test ray` the ray test (the code of pilot 1's patch,
brought up to date: branch `ray-target-47`; this script runs whichever the installed
`DepthOccupancy` has and records the commit). Rule: the ray test replaces the sphere if,
summed over the twelve blocked rows, it collides at least a third less often and loses at
most 24 successes of 1200 (2%), and it loses at most 3 standard successes of 600; then the
told test rows over seeds are run again with it. Otherwise nothing changes and this file
says so.

    python results/stage2/noise/ray_test.py --test sphere
    python results/stage2/noise/ray_test.py --test ray
    python results/stage2/noise/ray_test.py --summary

One JSON line per (test, row, views, K, family) in ray_test.jsonl (per task: success,
collision, steps; the blocked act median; the installed code's commit).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from target_test import COUNTS, installed_test, read_lines, run, run_missing

HERE = Path(__file__).resolve().parent
OUT = HERE / "ray_test.jsonl"
OFFSET = 520_000
LEVELS = (0.003, 0.01)
ROWS = ("hybrid", "escapes")
VIEWS = (3, 2, 1)


def key_of(line: dict) -> tuple:
    return line["test"], line["row"], line["views"], line["noise_m"], line["family"]


def summary(lines: list[dict]) -> None:
    totals: dict[tuple, list[int]] = {}
    for line in sorted(lines, key=key_of):
        success, collided = int(np.sum(line["success"])), int(np.sum(line["collided"]))
        print(f"{line['test']:6} {line['row']:7} {line['views']} view(s) K = "
              f"{line['noise_m']:<5} {line['family']:9}: {success} / {len(line['success'])} "
              f"reached, {collided} collided")  # fmt: skip
        total = totals.setdefault((line["test"], line["family"]), [0, 0, 0])
        total[0] += success
        total[1] += collided
        total[2] += 1
    for (test, family), (success, collided, rows) in sorted(totals.items()):
        print(f"{test}, {family}, summed over {rows} rows: {success} reached, {collided} collided")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--test", choices=("sphere", "ray"))
    parser.add_argument("--summary", action="store_true", help="only print the comparison")
    args = parser.parse_args()
    lines = read_lines(OUT)
    if not args.summary:
        if args.test != installed_test():
            raise SystemExit(f"--test {args.test}: the installed map's is {installed_test()}")
        torch.set_num_threads(1)
        keys = [
            (args.test, row, views, noise_m, family)
            for noise_m in LEVELS
            for row in ROWS
            for views in VIEWS
            for family in COUNTS
        ]

        def one(test, row, views, noise_m, family):
            return {"test": test, "noise_m": noise_m,
                    **run(row, views, family, noise_m=noise_m, offset=OFFSET)}  # fmt: skip

        run_missing(keys, key_of, one, lines, OUT)
    summary(lines)


if __name__ == "__main__":
    main()
