"""Validation (session 44): how far off its course a moving target may go before RRT on the
depth map plans again to meet it (`DepthShieldPlanner(track_m=...)`; protocol in README.md,
"Session 44: RRT on the depth map meeting a moving target").

    python results/stage2/shield/moving_track.py [--views 2] [--num-tasks 40]
    python results/stage2/shield/moving_track.py --hybrid 0.02
    python results/stage2/shield/moving_track.py --latency

`depth_planner.depth_rrt(views, track_m=T)` for each T of `TRACKS` (0: session 43's baseline,
which plans to where the target is), on `--num-tasks` validation tasks (offset 460000 into the
validation range) of each obstacle family, with the target moving at 0.1 and 0.2 m/s. One line
per (views, track, family, speed) in `moving_track.jsonl`: successes, collisions, plans and
the mean steps of the successes; then the rule's choice. With `--hybrid T`: the shipped
residual of `--views` in its hybrid (`depth_planner.HYBRID`) as committed (track 0) and with
its planner meeting the target (`track_m` T), lines marked `"hybrid": true` (added to the
file's other lines). With `--latency`: the planner meeting the target (`TRACK_M`) acting in
real time at 0.2 m/s (`run_episode(real_time=True)`), without and with
`DepthShieldPlanner(latency=True)`, lines marked `"latency"` (false / true) and
`"real_time": true`.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import torch
from moving_targets import outcomes  # (this directory: the script's own)

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import HYBRID, TRACK_M, depth_rrt
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.policies import load_policy, views_suffix

HERE = Path(__file__).resolve().parent
OFFSET = 460_000
SPEEDS = (0.1, 0.2)
TRACKS = (0.0, 0.01, 0.02, 0.04)


def measure(
    views: int,
    track: float,
    family: str,
    speed: float,
    seeds,
    hybrid: bool,
    latency: bool | None = None,
) -> dict:
    """One setting on `seeds` of `family`; `latency` not None: in real time, the planner
    expecting its own latency or not."""
    if hybrid:
        residual, _, env_kwargs = load_policy(f"residual-{views_suffix(views)}")
        policy, env_kwargs = replace(HYBRID[views], track_m=track).around(residual, env_kwargs)
    else:
        policy, env_kwargs = depth_rrt(views, track_m=track)
    env = ReachEnv(num_obstacles=2, task_family=family, target_speed=speed, **env_kwargs)
    if latency is not None:
        policy.latency = latency
    tic = time.perf_counter()
    records = evaluate(env, policy, seeds, real_time=latency is not None)
    env.close()
    return {
        **({"hybrid": True} if hybrid else {}),
        **({"latency": latency, "real_time": True} if latency is not None else {}),
        "views": views,
        "track_m": track,
        "family": family,
        "speed": speed,
        **outcomes(records),
        "plans": policy.num_plans,
        "wall_s": round(time.perf_counter() - tic, 1),
    }


def choose(lines: list[dict]) -> float:
    """The rule: most blocked successes over both speeds, then most standard, then larger."""

    def total(track: float, family: str) -> int:
        return sum(x["successes"] for x in lines if x["track_m"] == track and x["family"] == family)

    tracks = [t for t in TRACKS if t > 0]
    return max(tracks, key=lambda t: (total(t, "blocked"), total(t, "obstacles"), t))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-tasks", type=int, default=40)
    parser.add_argument("--views", type=int, default=2, choices=(3, 2, 1))
    parser.add_argument("--hybrid", type=float, default=None, metavar="T")
    parser.add_argument("--latency", action="store_true")
    args = parser.parse_args()
    seeds = VALIDATION_SEEDS.seeds(args.num_tasks, VALIDATION_SEEDS.start + OFFSET)
    out = HERE / "moving_track.jsonl"
    hybrid = args.hybrid is not None
    torch.set_num_threads(1)
    kept = []
    if out.exists():
        kept = [json.loads(line) for line in out.read_text().splitlines()]
        if args.latency:
            kept = [line for line in kept if "latency" not in line]
        else:
            kept = [line for line in kept if line.get("hybrid", False) != hybrid]
    lines = []
    with out.open("w") as f:
        for line in kept:
            f.write(json.dumps(line) + "\n")
        if args.latency:
            for latency in (False, True):
                for family in ("blocked", "obstacles"):
                    line = measure(args.views, TRACK_M, family, 0.2, seeds, False, latency)
                    print(json.dumps(line), flush=True)
                    f.write(json.dumps(line) + "\n")
                    f.flush()
            print("wrote", out)
            return
        for track in (0.0, args.hybrid) if hybrid else TRACKS:
            for family in ("blocked", "obstacles"):
                for speed in SPEEDS:
                    line = measure(args.views, track, family, speed, seeds, hybrid)
                    lines.append(line)
                    print(json.dumps(line), flush=True)
                    f.write(json.dumps(line) + "\n")
                    f.flush()
    print("wrote", out)
    if not hybrid:
        print("chosen track_m:", choose(lines))


if __name__ == "__main__":
    main()
