"""Reset cost: `CLAMGen/ReachBlocked-v0` against `CLAMGen/ReachObstacles-v0`, in the same run.

A blocked-path reset samples start and goal, checks the obstacle-blind joint path once and puts
an obstacle on it (`clamgen.tasks.blocked`), without rolling anything out; an obstacle reset
samples obstacles and checks the goal's IK solutions and the start. Both envs observe joints
only (no rendering), reset on the same training-range seeds, interleaved in blocks so that load
from other processes affects both alike.

    python benchmarks/reset_cost.py [--num-resets 300]

Prints the median and mean reset time of each and their ratio, writes
results/benchmarks/reset_cost.csv.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

import clamgen  # noqa: F401
from clamgen.experiments.config import TRAINING_SEEDS

ENV_IDS = {"blocked": "CLAMGen/ReachBlocked-v0", "obstacles": "CLAMGen/ReachObstacles-v0"}
BLOCK = 20  # resets of one env before switching to the other
FIRST_SEED = TRAINING_SEEDS.start + 7_000_000  # training seeds no run resets with by default


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-resets", type=int, default=300, help="resets per env")
    args = parser.parse_args()
    if args.num_resets < BLOCK:
        raise SystemExit(f"--num-resets must be >= {BLOCK}")
    envs = {name: gym.make(env_id).unwrapped for name, env_id in ENV_IDS.items()}
    times: dict[str, list[float]] = {name: [] for name in envs}
    for env in envs.values():
        env.reset(seed=0)  # warm-up
    for first in range(0, args.num_resets, BLOCK):
        seeds = FIRST_SEED + np.arange(first, min(first + BLOCK, args.num_resets))
        for name, env in envs.items():
            for seed in seeds:
                start = time.perf_counter()
                env.reset(seed=int(seed))
                times[name].append(time.perf_counter() - start)
    stats = {
        name: (
            float(np.median(t)) * 1e3,
            float(np.mean(t)) * 1e3,
            float(np.percentile(t, 95)) * 1e3,
        )
        for name, t in times.items()
    }
    for name, (median, mean, p95) in stats.items():
        print(
            f"{ENV_IDS[name]:<28} reset: median {median:7.2f} ms, mean {mean:7.2f} ms, "
            f"p95 {p95:7.2f} ms"
        )
    ratio_median = stats["blocked"][0] / stats["obstacles"][0]
    ratio_mean = stats["blocked"][1] / stats["obstacles"][1]
    print(f"blocked / obstacles: {ratio_median:.2f}x (median), {ratio_mean:.2f}x (mean)")
    path = write_csv(
        "reset_cost",
        [
            {
                "benchmark": "reset_blocked_vs_obstacles",
                "blocked_median_ms": round(stats["blocked"][0], 3),
                "obstacles_median_ms": round(stats["obstacles"][0], 3),
                "blocked_mean_ms": round(stats["blocked"][1], 3),
                "obstacles_mean_ms": round(stats["obstacles"][1], 3),
                "blocked_p95_ms": round(stats["blocked"][2], 3),
                "obstacles_p95_ms": round(stats["obstacles"][2], 3),
                "ratio_median": round(ratio_median, 3),
                "ratio_mean": round(ratio_mean, 3),
                "num_resets": args.num_resets,
            }
        ],
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
