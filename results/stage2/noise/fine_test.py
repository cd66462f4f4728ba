"""Validation pilot (session 46, third): with noisy depth, the told hybrids' map on the policy's
own 64-pixel views instead of their 128-pixel depth cameras.

The 3- and 2-view hybrids read a 128-pixel depth camera per view (`--depth-fine-size 128`,
chosen in session 18 on exact depth). Told the noise, their acts take 2.16 / 1.72 ms from 3 / 2
views at K = 0.003 and 2.90 / 1.92 ms at K = 0.01 (`benchmarks/act_latency.py --depth-noise-m`):
most of the 4 x 128^2 or 2 x 128^2 pixels change every frame and are lifted and tested again.
On the policy's 64-pixel views (`fine_depth_size=0`) the map has a quarter of the pixels; with
the noise, the finer camera's detail may buy less than it did on exact depth.

Protocol (written before any run): the shipped 3- and 2-view residuals in their hybrids told the
noise (`HYBRID[v]` with `noise_m=K`), the shield on 128-pixel cameras (`--test fine-128`, as
shipped) against the policy's views (`--test fine-64`), K = 0.003 and 0.01, on 100 blocked and
50 standard validation tasks from offset 500000 (a block no earlier check used), the same tasks
for both. Rule: `fine-64` is recommended with noisy depth if, summed over the four blocked
rows, it loses at most 4 successes of 400 and collides at most 4 more times, and its blocked
act median is lower in each row. Otherwise this file says so and nothing changes.

    python results/stage2/noise/fine_test.py --test fine-128
    python results/stage2/noise/fine_test.py --test fine-64
    python results/stage2/noise/fine_test.py --summary

One JSON line per (test, views, K, family) in fine_test.jsonl (per task: success, collision,
steps; the blocked act median).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from target_test import installed_commit, read_lines, run_missing  # (this folder's pilots)

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.evaluate import evaluate, per_task
from clamgen.experiments.machine import describe
from clamgen.experiments.policies import load_policy

HERE = Path(__file__).resolve().parent
OUT = HERE / "fine_test.jsonl"
OFFSET = 500_000
LEVELS = (0.003, 0.01)
COUNTS = {"blocked": 100, "obstacles": 50}
TESTS = {"fine-128": 128, "fine-64": 0}
"""The shield's depth camera: 128-pixel (as shipped) or the policy's own views (0)."""
POLICIES = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}


def evaluate_hybrid(guard, views: int, noise_m: float, family: str, offset: int) -> dict:
    """The shipped residual of `views` views through `guard`, with depth noise `noise_m`, on
    `COUNTS[family]` validation tasks of `family` from `offset`: the JSON line's fields but
    the row's own (this pilot's and `lift_test.py`'s)."""
    policy, _, env_kwargs = load_policy(POLICIES[views])
    hybrid, env_kwargs = guard.around(policy, env_kwargs)
    env = ReachEnv(num_obstacles=2, task_family=family, depth_noise_m=noise_m, **env_kwargs)
    first = VALIDATION_SEEDS.start + offset
    seeds = [int(s) for s in VALIDATION_SEEDS.seeds(COUNTS[family], first)]
    records = evaluate(env, hybrid, seeds)
    env.close()
    return {"flags": list(guard.flags()), "seeds": seeds, **per_task(records),
            "machine": describe()}  # fmt: skip


def pilot_line(test: str, views: int, noise_m: float, family: str, guard, offset: int) -> dict:
    """One row's JSON line of a pilot whose rows are (test, views, K, family) and whose tests
    differ in `guard`: the row, `evaluate_hybrid`'s fields and the installed code's commit
    (this pilot's, `lift_test.py`'s and `own_views_test.py`'s)."""
    return {"test": test, "views": views, "noise_m": noise_m, "family": family,
            **evaluate_hybrid(guard, views, noise_m, family, offset),
            "commit": installed_commit()}  # fmt: skip


def run(test: str, views: int, noise_m: float, family: str) -> dict:
    guard = replace(HYBRID[views], fine_depth_size=TESTS[test], noise_m=noise_m)
    return pilot_line(test, views, noise_m, family, guard, OFFSET)


def summary(lines: list[dict]) -> None:
    """Each line's blocked and standard counts and act median; per test, the blocked sums."""
    totals: dict[str, list[int]] = {}
    for line in lines:
        success, collided = int(np.sum(line["success"])), int(np.sum(line["collided"]))
        print(f"{line['test']:8} {line['views']} view(s) K = {line['noise_m']:<5} "
              f"{line['family']:9}: {success} / {len(line['success'])} reached, {collided} "
              f"collided, act median {line['act_median_ms']:.2f} ms")  # fmt: skip
        if line["family"] == "blocked":
            total = totals.setdefault(line["test"], [0, 0, 0])
            total[0] += success
            total[1] += collided
            total[2] += 1
    for test, (success, collided, rows) in totals.items():
        print(f"{test}: blocked, summed over {rows} rows: {success} reached, {collided} collided")


def pilot_main(doc: str, tests, views, run, out: Path, levels=LEVELS) -> None:
    """The command line of a pilot whose rows are (test, views, K, family) for K in `levels`,
    `run(*row)` one row's JSON line, written to `out` (this pilot's and `lift_test.py`'s)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--test", choices=tuple(tests))
    parser.add_argument("--summary", action="store_true", help="only print the comparison")
    args = parser.parse_args()
    lines = read_lines(out)
    if not args.summary:
        torch.set_num_threads(1)
        keys = [
            (args.test, number, noise_m, family)
            for number in views
            for noise_m in levels
            for family in COUNTS
        ]
        run_missing(
            keys, lambda x: (x["test"], x["views"], x["noise_m"], x["family"]), run, lines, out
        )
    summary(lines)


if __name__ == "__main__":
    pilot_main(__doc__, TESTS, (3, 2), run, OUT)
