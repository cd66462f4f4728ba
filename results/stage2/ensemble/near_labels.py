"""How a 3-view student's actions match the teacher's labels near the target (session 52; a
description, nothing chosen on it).

`stalls.py` found the students' stalls to be near misses, the tip a few centimetres from the
target. Here, on the states of a memory-mapped pool (`--pool`, default session 50's
previous-action pool, the only 3-view pool on this machine), split by the tip's distance to
the target: how many states lie there, the mean squared error between the student's action
and the teacher's label after the tanh, their mean lengths (6 joints, each in [-1, 1]), and
the cosine between them (median, and the share pointing away from each other). A student
regressed on another pool (`--policy`, default the shipped recipe's regression, seed 7) reads
these states as it would its own; `--states` per band, seeded.

    python results/stage2/ensemble/near_labels.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clamgen.experiments.policies import load_policy

BANDS_M = ((0.02, 0.05), (0.05, 0.10), (0.10, np.inf))
"""Tip-to-target distance bands (m); success is within 0.02."""
POOL = Path("runs/pool-cache/d3-prev4")
"""The memory-mapped pool these descriptions read by default (session 50's previous-action
pool, written by `offline.py --pool-cache`)."""
BATCH = 250


def band_name(low: float, high: float) -> str:
    """A band of `BANDS_M` as the outputs name it."""
    return f"over {low * 100:.0f} cm" if high == np.inf else f"{low * 100:.0f}-{high * 100:.0f} cm"


def open_pool(parser: argparse.ArgumentParser, pool: Path, keys) -> dict[str, np.ndarray]:
    """The pool's arrays named in `keys`, memory-mapped read-only; a missing pool is the
    parser's one-line error."""
    if not (pool / "images.npy").exists():
        parser.error(f"{pool}: no memory-mapped pool (offline.py --pool-cache writes one)")
    return {key: np.load(pool / f"{key}.npy", mmap_mode="r") for key in keys}


def row_cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cosine of two (N, A) arrays."""
    norms = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    return (a * b).sum(1) / np.maximum(norms, 1e-9)


def student_actions(agent, arrays: dict, inputs, index: np.ndarray, batch: int) -> np.ndarray:
    """(N, A) the actions (tanh of the pre-squash means) `agent` takes on the pool's rows
    `index`, reading the arrays named in `inputs`, `batch` rows at a time."""
    means = []
    for start in range(0, len(index), batch):
        rows = index[start : start + batch]
        means.append(agent.mean_action({key: np.asarray(arrays[key][rows]) for key in inputs}))
    return np.tanh(np.concatenate(means))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pool", type=Path, default=POOL)
    parser.add_argument(
        "--policy", default="results/stage2/ensemble/levers33/d3-pool4-48k-s7_policy.pt"
    )
    parser.add_argument("--states", type=int, default=1500)
    args = parser.parse_args()
    keys = ("images", "observation", "achieved_goal", "desired_goal", "label")
    arrays = open_pool(parser, args.pool, keys)
    distance = np.linalg.norm(arrays["achieved_goal"] - arrays["desired_goal"], axis=1)
    agent = load_policy(args.policy)[0].agent
    rng = np.random.default_rng(0)
    print(f"{args.pool}: {len(distance)} states; student {args.policy}")
    inputs = [key for key in arrays if key != "label"]
    for low, high in BANDS_M:
        band = np.flatnonzero((distance >= low) & (distance < high))
        index = np.sort(rng.choice(band, min(args.states, len(band)), replace=False))
        action = student_actions(agent, arrays, inputs, index, BATCH)
        label = np.tanh(np.asarray(arrays["label"][index]))
        lengths = np.linalg.norm(action, axis=1), np.linalg.norm(label, axis=1)
        cosine = row_cosine(action, label)
        error = ((action - label) ** 2).mean()
        name = band_name(low, high)
        share = len(band) / len(distance)
        print(
            f"{name}: {len(band)} states ({share:.2f}); action "
            f"error {error:.3f} (mean square); length: label {lengths[1].mean():.2f}, student "
            f"{lengths[0].mean():.2f}; cosine median {np.median(cosine):.2f}, "
            f"below 0 {(cosine < 0).mean():.2f}"
        )


if __name__ == "__main__":
    main()
