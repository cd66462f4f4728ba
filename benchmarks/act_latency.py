"""Acting latency of the shipped vision policies on one core, against a reference in the run.

Each policy acts at batch 1 (deterministic: the tanh of the mean, as in every table) on
observations rendered from its own cameras, with one torch thread. The reference is the
RL-trained 2-view residual shipped before the distilled ones (`tests/data/residual-2views-rl.pt`,
the same architecture as `residual-2views`), timed interleaved in blocks with the others so
that load from other processes affects all alike. The blocked-path issue's aim: under 2 ms a
step on one core.

The shipped policies acting through the depth shield (`clamgen eval --depth-shield-m 0.01`;
for one view also with `--depth-shadow-m 0.05 --depth-shadow-behind-surfaces`; and as the
hybrids without their planners, the shield reading 128-pixel depth cameras,
`--depth-fine-size 128`, for one view with the unseen-space test; and with random escapes
from stalls instead of the planner, `depth_planner.ESCAPES`) are timed
along whole episodes of their own on blocked and standard tasks (8 of each), recorded first,
so that the shield sees a growing obstacle map and steps that need it (and a policy pressed
against an obstacle until the time limit), as in an evaluation (its cost includes the
policy's).

    python benchmarks/act_latency.py [--num-calls 400] [--extra POLICY ...] [--policies-only]
        [--in-episodes] [--depth-noise-m K] [--no-csv]

With `--in-episodes`, every row (the policies alone too) acts in live episodes instead, on
the same blocked and standard tasks, its act timed between the env's steps as `clamgen eval`
times it: the env renders the next views in between, so the policy's weights and the shield's
arrays are no longer in the CPU's caches (in evaluations the shielded 3-view policy's act took
about twice its time in the replay). The rows take turns episode by episode.

With `--depth-noise-m K`, every row's views (and the shield's depth cameras) carry a depth
camera's noise, sd K z^2 m (`ReachEnv(depth_noise_m=K)`), and the shielded rows' maps are told
it (`--depth-noise-model-m K`): the told wrappers' act time, against the same reference.

Prints each policy's median and 95th-percentile act time and its ratio to the reference's
median; writes results/benchmarks/act_latency.csv (act_latency_in_episodes.csv with
`--in-episodes`; `_noise_k<K>` before `.csv` with noise) unless --no-csv. `--extra` adds
other policy files (alone), `--policies-only` leaves out the shielded rows.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

from clamgen.envs import ReachEnv
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.depth_planner import ESCAPES, HYBRID, DepthGuard
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.policies import load_policy
from clamgen.experiments.tables import ACT_AIM_MS

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ("RL 2-view residual (reference)", str(ROOT / "tests/data/residual-2views-rl.pt"))
POLICIES = (
    ("residual-3views", "residual-3views"),
    ("residual-2views", "residual-2views"),
    ("residual-1view", "residual-1view"),
    REFERENCE,
)
SHIELD = DepthGuard()
"""The shield alone (`clamgen eval --depth-shield-m 0.01`)."""
HIDDEN = replace(HYBRID[1], planner=False, fine_depth_size=0)
"""With the unseen-space test as chosen for one view (`--depth-shadow-m 0.05
--depth-shadow-behind-surfaces`)."""
FINE = {views: replace(guard, planner=False) for views, guard in HYBRID.items()}
"""The hybrids without their planners: the shield reading 128-pixel depth cameras
(`--depth-fine-size 128`), for one view with the unseen-space test."""
SHIELDED = (
    ("residual-3views", SHIELD),
    ("residual-2views", SHIELD),
    ("residual-1view", SHIELD),
    ("residual-1view", HIDDEN),
    ("residual-3views", FINE[3]),
    ("residual-2views", FINE[2]),
    ("residual-1view", FINE[1]),
    *(
        (name, ESCAPES[views])
        for views, name in ((3, "residual-3views"), (2, "residual-2views"), (1, "residual-1view"))
    ),
)
NUM_EPISODES = 8
BLOCK = 50  # calls of one policy before switching to the next
NUM_OBSERVATIONS = 20
FIRST_SEED = TRAINING_SEEDS.start + 7_500_000  # training seeds no run resets with by default


def observations(env_kwargs: dict) -> list[dict]:
    env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
    obs = [env.reset(seed=FIRST_SEED + i)[0] for i in range(NUM_OBSERVATIONS)]
    env.close()
    return obs


def episodes(policy, env_kwargs: dict) -> list[list[dict]]:
    """Observations of `NUM_EPISODES` episodes of `policy` (a shielded one) on each of the
    blocked-path and the standard obstacle tasks, as the tables run it."""
    out = []
    for family in ("blocked", "obstacles"):
        env = ReachEnv(num_obstacles=2, task_family=family, **env_kwargs)
        for i in range(NUM_EPISODES):
            seen: list[dict] = []
            run_episode(env, policy, FIRST_SEED + i, on_step=lambda obs, *_, s=seen: s.append(obs))
            out.append(seen[:-1])  # (the observation after the last step is not acted on)
        env.close()
    return out


class Live:
    """A policy acting in live episodes on the blocked and the standard tasks in turn
    (`NUM_EPISODES` of each), its act timed as in `clamgen.experiments.evaluate.run_episode`."""

    def __init__(self, policy, env_kwargs: dict) -> None:
        self.policy = policy
        self.envs = [
            ReachEnv(num_obstacles=2, task_family=family, **env_kwargs)
            for family in ("blocked", "obstacles")
        ]
        self.episode = 0

    def next_episode(self) -> list[float]:
        env = self.envs[self.episode % 2]
        seed = FIRST_SEED + (self.episode // 2) % NUM_EPISODES
        self.episode += 1
        return run_episode(env, self.policy, seed).act_times_s


class Replay:
    """A shielded policy acting along recorded episodes, resetting it at each start."""

    def __init__(self, policy, recorded: list[list[dict]]) -> None:
        self.policy = policy
        self.steps = [(i == 0, obs) for episode in recorded for i, obs in enumerate(episode)]
        self.cursor = 0

    def next(self) -> dict:
        first, obs = self.steps[self.cursor % len(self.steps)]
        if first:
            self.policy.reset()
        self.cursor += 1
        return obs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--num-calls",
        type=int,
        default=400,
        help="act calls per policy (at least: a shielded one replays every recorded step "
        "equally often)",
    )
    parser.add_argument("--extra", nargs="*", default=[], metavar="POLICY", help="more policies")
    parser.add_argument("--policies-only", action="store_true", help="no shielded rows")
    parser.add_argument(
        "--in-episodes",
        action="store_true",
        help="time every row's acts in live episodes, between env steps, as evaluations do",
    )
    parser.add_argument(
        "--depth-noise-m",
        type=float,
        default=0.0,
        metavar="K",
        help="noisy depth, sd K z^2 m, the shielded rows' maps told it (default: exact depth)",
    )
    parser.add_argument("--no-csv", action="store_true")
    args = parser.parse_args()
    if not 0 <= args.depth_noise_m < float("inf"):
        raise SystemExit(f"--depth-noise-m must be a number >= 0, got {args.depth_noise_m}")
    noise = {"depth_noise_m": args.depth_noise_m} if args.depth_noise_m else {}
    torch.set_num_threads(1)
    loaded = {}
    for label, name in (*POLICIES, *((path, path) for path in args.extra)):
        policy, _, env_kwargs = load_policy(name)
        env_kwargs = env_kwargs | noise
        source = Live(policy, env_kwargs) if args.in_episodes else observations(env_kwargs)
        loaded[label] = (policy, source)
    for name, guard in () if args.policies_only else SHIELDED:
        policy, _, env_kwargs = load_policy(name)
        guard = replace(guard, noise_m=args.depth_noise_m)
        shielded = guard.wrap(policy, env_kwargs["num_views"], env_kwargs["image_size"])
        env_kwargs = env_kwargs | guard.env_kwargs() | noise
        if args.in_episodes:
            source = Live(shielded, env_kwargs)
        else:
            source = Replay(shielded, episodes(shielded, env_kwargs))
        label = f"{name} + depth shield ({guard.margin_m} m"
        label += f", shadow {guard.shadow_m} m" if guard.shadow_m is not None else ""
        label += f", depth at {guard.fine_depth_size} px" if guard.fine_depth_size else ""
        label += ", random escapes" if guard.escapes else ""
        label += f", told noise {guard.noise_m:g}" if guard.noise_m else ""
        loaded[label + ")"] = (shielded, source)
    times = time_live(loaded) if args.in_episodes else time_calls(loaded, args.num_calls)
    stem = "act_latency_in_episodes" if args.in_episodes else "act_latency"
    stem += f"_noise_k{args.depth_noise_m:g}".replace(".", "p") if args.depth_noise_m else ""
    report(times, stem, args.no_csv)


def time_live(loaded: dict) -> dict[str, list[float]]:
    """Each row's act times over its live episodes, the rows taking turns episode by episode."""
    times: dict[str, list[float]] = {label: [] for label in loaded}
    for _ in range(2 * NUM_EPISODES):
        for label, (_, live) in loaded.items():
            times[label] += live.next_episode()
    return times


def time_calls(loaded: dict, num_calls: int) -> dict[str, list[float]]:
    """Each row's act times on its observations (replayed episodes for a shielded one), the
    rows taking turns in blocks of `BLOCK` calls."""
    times: dict[str, list[float]] = {label: [] for label in loaded}
    # A shielded policy replays all its recorded steps the same number of times.
    calls = {
        label: len(obs.steps) * -(-num_calls // len(obs.steps))
        if isinstance(obs, Replay)
        else num_calls
        for label, (_, obs) in loaded.items()
    }
    for start in range(0, max(calls.values()), BLOCK):
        for label, (policy, obs) in loaded.items():
            for i in range(start, min(start + BLOCK, calls[label])):
                ob = obs.next() if isinstance(obs, Replay) else obs[i % len(obs)]
                tic = time.perf_counter()
                policy.act(ob)
                times[label].append(time.perf_counter() - tic)
    return times


def report(times: dict[str, list[float]], csv_name: str, no_csv: bool) -> None:
    """Print each row's median and 95th percentile and its ratio to the reference's median;
    write them to `csv_name`.csv unless `no_csv`."""
    reference = float(np.median(times[REFERENCE[0]])) * 1e3
    rows = []
    width = max(map(len, times))
    for label, values in times.items():
        ms = np.asarray(values) * 1e3
        row = {
            "policy": label,
            "median_ms": round(float(np.median(ms)), 4),
            "p95_ms": round(float(np.percentile(ms, 95)), 4),
            "ratio_to_reference": round(float(np.median(ms)) / reference, 3),
            "under_aim": bool(np.median(ms) < ACT_AIM_MS),
        }
        rows.append(row)
        print(
            f"{label:{width}s} median {row['median_ms']:.3f} ms  p95 {row['p95_ms']:.3f} ms  "
            f"x{row['ratio_to_reference']:.2f} of the reference  "
            f"({'under' if row['under_aim'] else 'over'} the {ACT_AIM_MS} ms aim)"
        )
    if not no_csv:
        print("wrote", write_csv(csv_name, rows))


if __name__ == "__main__":
    main()
