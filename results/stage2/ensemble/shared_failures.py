"""Which blocked tasks do all three 3-view seeds fail? Task geometry by outcome (a diagnosis).

The three seeds of the 3-view recipe fail 19 of block 170000's 300 blocked validation tasks
together (`ensemble_170000.jsonl`, README "The mean of the three 3-view seeds"). This resets
each of those tasks without rendering and compares their geometry with the tasks all three
solve: how close the target and the start tip are to the nearest obstacle surface, how
small the obstacles are, and how far the target is from the arm's base. Per group it prints
the median and quartiles and the Mann-Whitney U test's P (two-sided). Then, for every policy
on the block, its blocked success on the tasks whose target lies within `--near-m` of an
obstacle and on the others, with Wilson 95% intervals. Chooses nothing.

    python results/stage2/ensemble/shared_failures.py [--block ensemble_170000.jsonl]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.stats import mannwhitneyu

from clamgen.envs import ReachEnv
from clamgen.experiments.distill import target_clearance_m
from clamgen.experiments.tables import wilson_interval

HERE = Path(__file__).resolve().parent
SEEDS = ("3v-s5", "3v-s7", "3v-s8")


def _rate(success: np.ndarray) -> str:
    low, high = wilson_interval(int(success.sum()), len(success))
    return f"{success.mean():.3f} ({low:.3f}-{high:.3f})"


def _clearance(point: np.ndarray, obstacles: np.ndarray) -> float:
    return float(target_clearance_m(point[None], obstacles[None])[0])


def geometry(seeds: list[int]) -> dict[int, dict[str, float]]:
    """Each blocked task's geometry, from one env reset per task (nothing rendered)."""
    env = ReachEnv(num_obstacles=2, task_family="blocked", include_obstacle_state=True)
    out = {}
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        obstacles, tip, goal = obs["obstacles"], obs["achieved_goal"], obs["desired_goal"]
        out[seed] = {
            "target to obstacle (m)": _clearance(goal, obstacles),
            "start tip to obstacle (m)": _clearance(tip, obstacles),
            "smallest half size (m)": float(obstacles[:, 5:8].min()),
            "start tip to target (m)": float(np.linalg.norm(goal - tip)),
            "target to base, horizontal (m)": float(np.linalg.norm(goal[:2])),
            "target height (m)": float(goal[2]),
        }
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--block", type=Path, default=HERE / "ensemble_170000.jsonl")
    parser.add_argument("--near-m", type=float, default=0.02, help="a target this close is near")
    args = parser.parse_args()
    lines = [json.loads(line) for line in args.block.read_text().splitlines() if line]
    by = {x["policy"]: x for x in lines if x["family"] == "blocked"}
    seeds = next(iter(by.values()))["seeds"]
    tasks = geometry(seeds)
    if all(name in by for name in SEEDS):
        compare_geometry(by, tasks)
    near = np.array([tasks[s]["target to obstacle (m)"] < args.near_m for s in seeds])
    print(f"{near.sum()} of {len(seeds)} blocked tasks have their target within {args.near_m} m")
    for name, line in by.items():
        if line["seeds"] == seeds:
            won = np.array(line["success"])
            print(f"{name:24s} near {_rate(won[near])}, the others {_rate(won[~near])}")


def compare_geometry(by: dict[str, dict], tasks: dict[int, dict[str, float]]) -> None:
    """The geometry of the tasks every one of SEEDS fails against those they all solve."""
    success = np.array([by[name]["success"] for name in SEEDS])
    seeds = np.array(by[SEEDS[0]]["seeds"])
    groups = {"all fail": seeds[~success.any(0)], "all solve": seeds[success.all(0)]}
    features = {name: [tasks[int(s)] for s in group] for name, group in groups.items()}
    print(", ".join(f"{name}: {len(group)} tasks" for name, group in groups.items()))
    for key in features["all fail"][0]:
        values = {name: np.array([f[key] for f in rows]) for name, rows in features.items()}
        p = mannwhitneyu(values["all fail"], values["all solve"]).pvalue
        text = "; ".join(
            f"{name} {np.median(v):.3f} ({np.quantile(v, 0.25):.3f}-{np.quantile(v, 0.75):.3f})"
            for name, v in values.items()
        )
        print(f"{key:32s} {text}; P = {p:.3f}")


if __name__ == "__main__":
    main()
