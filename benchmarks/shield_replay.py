"""Replay recorded episodes through the depth-shield hybrids: that a change to the shield keeps
its actions bit for bit, and where its time goes.

`record` runs the shipped vision policies through the hybrids' shields (without their
planners: `HYBRID` with `planner=False`, the 3-, 2- and 1-view settings of
`clamgen eval --depth-hybrid`) and the 1-view shield with the unseen-space test on 64-pixel
depth, on blocked and standard tasks from training seeds no run resets with by default, and
keeps every observation and action. `check` acts again on the recorded observations with the
current code and counts the actions that differ (0 is the aim of an exact speed-up); it also
prints each setting's median act time. `profile` runs the replay of one setting under
cProfile.

    python benchmarks/shield_replay.py record runs/shield_replay.pkl [--episodes 4]
        [--depth-noise-m K]
    python benchmarks/shield_replay.py check runs/shield_replay.pkl
    python benchmarks/shield_replay.py profile runs/shield_replay.pkl --setting fine-3

With `--depth-noise-m K` the episodes are recorded on noisy depth (`ReachEnv(depth_noise_m=K)`)
through shields told the noise (`DepthGuard.noise_m`, `--depth-noise-model-m K`); the file
keeps K, and `check` and `profile` replay them the same way.
"""

from __future__ import annotations

import argparse
import cProfile
import pickle
import pstats
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from clamgen.envs import ReachEnv
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.depth_planner import HYBRID
from clamgen.experiments.policies import load_policy

FIRST_SEED = TRAINING_SEEDS.start + 7_600_000  # training seeds no run resets with by default
SETTINGS = {
    "fine-3": ("residual-3views", replace(HYBRID[3], planner=False)),
    "fine-2": ("residual-2views", replace(HYBRID[2], planner=False)),
    "fine-1": ("residual-1view", replace(HYBRID[1], planner=False)),
    "hidden-1": ("residual-1view", replace(HYBRID[1], planner=False, fine_depth_size=0)),
}
"""Name: (policy, the shield's settings)."""


NOISE_KEY = "depth_noise_m"
"""The recorded file's entry for the depth noise (absent: exact depth)."""


def shielded(setting: str, noise_m: float = 0.0):
    name, guard = SETTINGS[setting]
    guard = replace(guard, noise_m=noise_m)
    policy, _, env_kwargs = load_policy(name)
    wrapped = guard.wrap(policy, env_kwargs["num_views"], env_kwargs["image_size"])
    noise = {"depth_noise_m": noise_m} if noise_m else {}
    return wrapped, env_kwargs | guard.env_kwargs() | noise


def record(path: Path, episodes: int, noise_m: float = 0.0) -> None:
    out: dict[str, list | float] = {NOISE_KEY: noise_m}
    for setting in SETTINGS:
        policy, env_kwargs = shielded(setting, noise_m)
        out[setting] = []
        for family in ("blocked", "obstacles"):
            env = ReachEnv(num_obstacles=2, task_family=family, **env_kwargs)
            for i in tqdm(range(episodes), desc=f"{setting} {family}", leave=False):
                obs, _ = env.reset(seed=FIRST_SEED + i)
                policy.reset(env)
                seen, actions, done = [], [], False
                while not done:
                    action = policy.act(obs)
                    seen.append({key: np.array(value, copy=True) for key, value in obs.items()})
                    actions.append(np.array(action, copy=True))
                    obs, _, terminated, truncated, _ = env.step(action)
                    done = terminated or truncated
                out[setting].append((seen, actions))
            env.close()
        steps = sum(len(actions) for _, actions in out[setting])
        print(f"{setting}: {len(out[setting])} episodes, {steps} steps")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(out, f)
    print("wrote", path)


def replay(policy, episodes: list) -> tuple[int, int, list[float]]:
    """Act on every recorded step: (steps, actions that differ, act times in seconds)."""
    steps = differ = 0
    times = []
    for seen, actions in episodes:
        policy.reset()
        for obs, recorded in zip(seen, actions, strict=True):
            tic = time.perf_counter()
            action = policy.act(obs)
            times.append(time.perf_counter() - tic)
            steps += 1
            differ += int(not np.array_equal(action, recorded))
    return steps, differ, times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("record", "check", "profile"))
    parser.add_argument("path", type=Path, help="the recorded episodes (a pickle)")
    parser.add_argument("--episodes", type=int, default=4, help="per task family (record)")
    parser.add_argument("--setting", choices=tuple(SETTINGS), default="fine-3")
    parser.add_argument(
        "--depth-noise-m", type=float, default=0.0, metavar="K", help="noisy depth (record)"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.mode == "record":
        if not 0 <= args.depth_noise_m < float("inf"):
            sys.exit(f"error: --depth-noise-m must be a number >= 0, got {args.depth_noise_m}")
        record(args.path, args.episodes, args.depth_noise_m)
        return
    if not args.path.is_file():
        sys.exit(f"error: no recorded episodes at {args.path} (run `record` first)")
    with open(args.path, "rb") as f:
        recorded = pickle.load(f)
    noise_m = recorded.pop(NOISE_KEY, 0.0)
    if args.mode == "profile":
        policy, _ = shielded(args.setting, noise_m)
        profiler = cProfile.Profile()
        profiler.runcall(replay, policy, recorded[args.setting])
        pstats.Stats(profiler).sort_stats("tottime").print_stats(30)
        return
    total = 0
    for setting, episodes in recorded.items():
        policy, _ = shielded(setting, noise_m)
        steps, differ, times = replay(policy, episodes)
        total += differ
        print(
            f"{setting}: {differ} of {steps} actions differ; "
            f"median act {np.median(times) * 1e3:.3f} ms"
        )
    print("identical" if total == 0 else f"{total} actions differ")


if __name__ == "__main__":
    main()
