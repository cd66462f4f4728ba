"""Where a student's imitation error lies: before and after the tanh, on saturated labels.

    python results/stage2/distill/loss_split.py runs/offline/priv-fixed50-pool3-s7/policy.pt \
        runs/offline/priv-fixed50-tanh-pool3-s7/policy.pt

For each policy file, on the first `--states` states of a DAgger run's last iteration
(`--data`, default `priv-fixed50-s2`'s, which every `priv-fixed50` pooled student trained on):
the mean squared error of its pre-squash mean against the teacher's labels, the same after the
tanh (the actions taken), and the share of each that lies on the label components beyond
`--saturated` (tanh(2) = 0.96: a nearly full step). Prints one line per policy; session 52's
reason for the loss after the tanh (README, "The loss after the tanh").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clamgen.experiments.policies import load_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("policies", nargs="+", help="policy files of privileged students")
    parser.add_argument("--data", default="runs/distill/priv-fixed50-s2")
    parser.add_argument("--states", type=int, default=4000)
    parser.add_argument("--saturated", type=float, default=2.0)
    args = parser.parse_args()
    files = sorted(Path(args.data, "data").glob("iteration*.npz"))
    if not files:
        parser.error(f"no iteration*.npz under {args.data}/data")
    data = np.load(files[-1])
    obs = {k: data[k][: args.states] for k in data.files if k != "label"}
    labels = data["label"][: args.states]
    saturated = np.abs(labels) > args.saturated
    print(
        f"{files[-1]}: {len(labels)} states, {saturated.mean():.3f} of label components beyond "
        f"{args.saturated}"
    )
    for path in args.policies:
        agent = load_policy(path)[0].agent
        mean = agent.mean_action(obs)
        before = (mean - labels) ** 2
        after = (np.tanh(mean) - np.tanh(labels)) ** 2
        share_before = before[saturated].sum() / before.sum()
        share_after = after[saturated].sum() / after.sum()
        print(
            f"{path}: before the tanh {before.mean():.3f} ({share_before:.2f} of it on "
            f"saturated labels), after {after.mean():.3f} ({share_after:.2f})"
        )


if __name__ == "__main__":
    main()
