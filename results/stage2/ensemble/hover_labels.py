"""Do the teacher's labels agree where a student hovers, and does a student fit them there?
(session 54; a description, nothing chosen on it).

`near_labels.py` found the students' actions shorter and less aligned with the labels 2-5 cm
from the target, which is what regressing labels that disagree at nearby states looks like,
but did not show that they disagree. Here, on a memory-mapped pool (`--pool`, default session
50's previous-action pool): the pool stores each collection env's states in turn (two envs, so
a state's successor in its episode is two rows on, same obstacles and goal), so the labels of
a state and its successor can be compared where the tip barely moved between them (a hover:
under `HOVER_M`). Per band of tip-to-target distance: how many such pairs, and the cosine
between their labels (after the tanh). Then a student regressed on this very pool (`--policy`,
default `prev4-s7`) on `--states` hover states and as many far ones: its action's length and
cosine against the label, on states it was trained on.

    python results/stage2/ensemble/hover_labels.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from near_labels import (  # (this directory: the script's own)
    BANDS_M,
    POOL,
    band_name,
    open_pool,
    row_cosine,
    student_actions,
)

from clamgen.experiments.policies import load_policy

COLLECTION_ENVS = 2
"""Rows between a state and its successor in the pool (the DAgger runs' `env.num_envs`)."""
HOVER_M = 0.003
"""The tip moved less than this between a state and its successor: a hover."""
MOVING_M = 0.01
"""... more than this: moving."""
INPUTS = ("images", "observation", "achieved_goal", "desired_goal", "previous_action")
BATCH = 200


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pool", type=Path, default=POOL)
    parser.add_argument(
        "--policy", default="results/stage2/ensemble/levers33/d3-prev4-48k-s7_policy.pt"
    )
    parser.add_argument("--states", type=int, default=800)
    args = parser.parse_args()
    arrays = open_pool(parser, args.pool, (*INPUTS, "label", "obstacles"))
    tip = np.asarray(arrays["achieved_goal"])
    goal = np.asarray(arrays["desired_goal"])
    scene = np.asarray(arrays["obstacles"]).reshape(len(tip), -1)
    label = np.tanh(np.asarray(arrays["label"]))
    lag = COLLECTION_ENVS
    # A state with a successor in its episode: the same scene and goal `lag` rows on.
    paired = np.zeros(len(tip), bool)
    paired[:-lag] = (np.abs(scene[lag:] - scene[:-lag]).max(1) < 1e-6) & (
        np.abs(goal[lag:] - goal[:-lag]).max(1) < 1e-6
    )
    moved = np.full(len(tip), np.inf)
    moved[:-lag] = np.linalg.norm(tip[lag:] - tip[:-lag], axis=1)
    agree = np.zeros(len(tip))
    agree[:-lag] = row_cosine(label[lag:], label[:-lag])
    distance = np.linalg.norm(tip - goal, axis=1)

    def in_band(low: float, high: float) -> np.ndarray:
        return paired & (distance >= low) & (distance < high)

    print(f"{args.pool}: {len(tip)} states, {paired.sum()} with a successor {lag} rows on")
    print("the teacher's labels at a state and its successor (cosine after the tanh):")
    for low, high in BANDS_M:
        band = in_band(low, high)
        for name, keep in (
            (f"tip moved under {HOVER_M * 1000:.0f} mm", moved < HOVER_M),
            (f"tip moved over {MOVING_M * 100:.0f} cm", moved > MOVING_M),
        ):
            rows = band & keep
            print(
                f"  {band_name(low, high)}, {name}: {rows.sum()} pairs; cosine median "
                f"{np.median(agree[rows]):.2f}, mean {agree[rows].mean():.2f}, below 0 "
                f"{(agree[rows] < 0).mean():.2f}; label length "
                f"{np.linalg.norm(label[rows], axis=1).mean():.2f}"
            )
    agent = load_policy(args.policy)[0].agent
    rng = np.random.default_rng(0)
    print(f"the student {args.policy} on states of the pool it was regressed on:")
    near, far = BANDS_M[0], BANDS_M[-1]  # the nearest band's hovers, and the farthest band
    groups = {
        f"hover {band_name(*near)} (tip moved under {HOVER_M * 1000:.0f} mm)": in_band(*near)
        & (moved < HOVER_M),
        band_name(*far): in_band(*far),
    }
    for name, rows in groups.items():
        index = np.sort(rng.choice(np.flatnonzero(rows), args.states, replace=False))
        action = student_actions(agent, arrays, INPUTS, index, BATCH)
        target = label[index]
        fit = row_cosine(action, target)
        print(
            f"  {name}: {rows.sum()} states; length label "
            f"{np.linalg.norm(target, axis=1).mean():.2f}, student "
            f"{np.linalg.norm(action, axis=1).mean():.2f}; cosine median {np.median(fit):.2f}, "
            f"mean {fit.mean():.2f}"
        )


if __name__ == "__main__":
    main()
