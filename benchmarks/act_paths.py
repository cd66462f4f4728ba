"""The vision policies' fast deterministic act against their module path, in live episodes.

Each shipped vision policy acts on blocked tasks (training seeds) in live episodes; at every
step it acts twice on the same observation, once through `clamgen.agents.fast_act` (what
`act` runs) and once through its modules (the reference, `agent.fast_act = None`), in turns
(the fast path first at even steps, the modules at odd ones), and only the first act of a step
is timed: that one runs right after the env rendered, with the renderer's data in the CPU's
caches, as every act of an evaluation does. Both acts must give the same action, bit for bit
(the benchmark stops otherwise). One torch thread.

    python benchmarks/act_paths.py [--episodes 10] [--no-csv]

Prints each policy's median act time both ways and their ratio (fast / modules; below 1 is
faster); writes results/benchmarks/act_paths.csv unless --no-csv.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

from clamgen.envs import ReachEnv
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.policies import load_policy
from clamgen.experiments.tables import ACT_AIM_MS

POLICIES = ("residual-3views", "residual-2views", "residual-1view", "image-only")
FIRST_SEED = TRAINING_SEEDS.start + 7_600_000  # training seeds no run resets with by default


def time_both(name: str, num_episodes: int) -> dict:
    """Median first-of-step act times (ms) of `name`'s fast path and module path."""
    policy, _, env_kwargs = load_policy(name)
    agent = policy.agent
    fast = agent.fast_act
    if fast is None:
        raise SystemExit(f"{name} has no fast act path")
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
    times: dict[bool, list[float]] = {True: [], False: []}
    step = 0
    for episode in range(num_episodes):
        obs, _ = env.reset(seed=FIRST_SEED + episode)
        done = False
        while not done:
            actions = {}
            for turn, use_fast in enumerate((step % 2 == 0, step % 2 == 1)):
                agent.fast_act = fast if use_fast else None
                start = time.perf_counter()
                actions[use_fast] = policy.act(obs)
                if turn == 0:
                    times[use_fast].append(time.perf_counter() - start)
            if not np.array_equal(actions[True], actions[False]):
                raise SystemExit(f"{name}: the two paths disagree at step {step}")
            obs, _, terminated, truncated, _ = env.step(actions[True])
            done = terminated or truncated
            step += 1
    agent.fast_act = fast
    env.close()
    fast_ms, modules_ms = (float(np.median(times[key]) * 1e3) for key in (True, False))
    return {
        "policy": name,
        "fast_median_ms": round(fast_ms, 4),
        "modules_median_ms": round(modules_ms, 4),
        "ratio_fast_to_modules": round(fast_ms / modules_ms, 3),
        "fast_under_aim": fast_ms < ACT_AIM_MS,
        "timed_acts_each": min(len(times[True]), len(times[False])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10, help="blocked episodes per policy")
    parser.add_argument("--no-csv", action="store_true")
    args = parser.parse_args()
    if args.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {args.episodes}")
    torch.set_num_threads(1)
    rows = []
    for name in POLICIES:
        row = time_both(name, args.episodes)
        rows.append(row)
        print(
            f"{name:16s} fast {row['fast_median_ms']:.3f} ms, modules "
            f"{row['modules_median_ms']:.3f} ms median: x{row['ratio_fast_to_modules']:.2f} "
            f"({row['timed_acts_each']} acts each; the same actions)"
        )
    if not args.no_csv:
        print(f"wrote {write_csv('act_paths', rows)}")


if __name__ == "__main__":
    main()
