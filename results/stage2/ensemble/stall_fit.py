"""Do the students fit the teacher's labels on the pool's stalled states? (a diagnosis)

Draws 600 states of the rebuilt four-run 3-view pool (`--pool-cache`), or of a DAgger
continuation's own collected states (`--continuation DIR`: `DIR/data/iteration*.npz`, the
states the student visited while it was continued), from each of three groups: stalled
(`clamgen.experiments.stall`: 10 or more steps since the tip last came 5 mm nearer its target)
within 4 cm of the target, stalled farther, and moving (fewer than 3 such steps), and prints
per group the labels' largest joint command (median) and, for each policy, its own (tanh of
its mean), the cosine to the label (median) and the squared error. Chooses nothing.

    python results/stage2/ensemble/stall_fit.py [--policies 3v-s7 3v-escape10]
    python results/stage2/ensemble/stall_fit.py --policies 3v-s7 \
        --continuation runs/offline/d3-pool4-48k-s7-dagger
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from ensemble import STUDENTS

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.policies import load_policy
from clamgen.experiments.pooled import cache_files, data_files
from clamgen.experiments.stall import pool_stall_counts

ROOT = Path(__file__).resolve().parents[3]
CACHE = ROOT / "runs" / "pool-cache" / "d3-pool4-48k"
PER_GROUP = 600
BATCH = 100
STALLED, MOVING, CLOSE_M = 10, 3, 0.04


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pool-cache", type=Path, default=CACHE)
    parser.add_argument("--continuation", type=Path, default=None, metavar="DIR")
    parser.add_argument("--policies", nargs="+", default=["3v-s7", "3v-escape10"])
    args = parser.parse_args()
    torch.set_num_threads(1)
    keys = ("images", "observation", "achieved_goal", "desired_goal", "label", "obstacles")
    if args.continuation is None:
        pool = {k: np.load(args.pool_cache / f"{k}.npy", mmap_mode="r") for k in keys}
        lengths = [rows for _, rows in cache_files(args.pool_cache)]
    else:
        chunks = [ckpt.load_npz(path) for path in data_files(args.continuation)]
        pool = {k: np.concatenate([chunk[k] for chunk in chunks]) for k in keys}
        lengths = [len(chunk["label"]) for chunk in chunks]
    counts = pool_stall_counts(
        pool["achieved_goal"], pool["desired_goal"], pool["obstacles"], lengths
    )
    distance = np.linalg.norm(pool["achieved_goal"] - pool["desired_goal"], axis=1)
    groups = {
        "stalled, within 4 cm": (counts >= STALLED) & (distance < CLOSE_M),
        "stalled, farther": (counts >= STALLED) & (distance >= CLOSE_M),
        "moving": counts < MOVING,
    }
    agents = {name: load_policy(STUDENTS[name])[0].agent for name in args.policies}
    rng = np.random.default_rng(0)
    for group, mask in groups.items():
        where = np.flatnonzero(mask)
        index = np.sort(rng.choice(where, min(PER_GROUP, len(where)), replace=False))
        obs = {k: np.asarray(pool[k][index]) for k in keys[:4]}
        label = np.tanh(np.asarray(pool["label"][index]))
        text = f"{group:22s} {mask.sum():6d} states; labels' largest command "
        text += f"{np.median(np.abs(label).max(1)):.2f}"
        for name, agent in agents.items():
            means = [
                agent.mean_action({k: v[i : i + BATCH] for k, v in obs.items()})
                for i in range(0, len(index), BATCH)
            ]
            action = np.tanh(np.concatenate(means))
            cosine = (action * label).sum(1) / np.linalg.norm(action, axis=1)
            cosine /= np.linalg.norm(label, axis=1)
            text += (
                f" | {name}: {np.median(np.abs(action).max(1)):.2f}, cosine "
                f"{np.median(cosine):.2f}, squared error {np.mean((action - label) ** 2):.3f}"
            )
        print(text)


if __name__ == "__main__":
    main()
