"""The first act of a fresh process, with the policy's warm-up (the package default) against
without it (the reference), in the same run.

`SACPolicy.reset` acts once on a blank observation at its first reset with an env, so that the
networks' first call in a process (kernels set up, their code loaded) is not timed as the first
step's act. Each measurement is a fresh process (`--child`) that loads the shipped
`residual-3views`, wraps it as the escape rows do (`depth_planner.ESCAPES`, the shield on
128-pixel depth cameras with random escapes), and runs `EPISODES` standard obstacle tasks
(validation seeds of a block no choice used), timing every act as `clamgen eval` does. The two
settings take turns, `--runs` processes each. With `--drop-caches` (root, Linux) the page cache
is dropped before every process, as on a machine that has not run the policy since boot.

    python benchmarks/first_act.py [--runs 3] [--drop-caches] [--no-csv]

Prints each setting's first act (median over the processes) and longest act, the ratio of the
reference's first act to the default's, and writes results/benchmarks/first_act.csv unless
--no-csv.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

FIRST_SEED = 2_000_395_000  # validation seeds (`VALIDATION_SEEDS`), a scratch block
EPISODES = 3
SETTINGS = ("warm-up (default)", "no warm-up (reference)")


def child(warm_up: bool) -> None:
    import torch

    from clamgen.envs import ReachEnv
    from clamgen.experiments.depth_planner import ESCAPES
    from clamgen.experiments.evaluate import run_episode
    from clamgen.experiments.policies import load_policy

    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy("residual-3views")
    if not warm_up:
        policy._warm = True  # as if warmed: the first act pays the set-up, as before
    guard = ESCAPES[env_kwargs["num_views"]]
    shielded = guard.wrap(policy, env_kwargs["num_views"], env_kwargs["image_size"])
    env = ReachEnv(num_obstacles=2, task_family="obstacles", **env_kwargs | guard.env_kwargs())
    acts: list[float] = []
    for i in range(EPISODES):
        acts += run_episode(env, shielded, FIRST_SEED + i).act_times_s
    env.close()
    ms = np.array(acts) * 1e3
    print(json.dumps({"first_ms": ms[0], "max_ms": ms.max(), "median_ms": float(np.median(ms))}))


def measure(warm_up: bool, drop_caches: bool) -> dict:
    if drop_caches:
        subprocess.run(["sync"], check=True)
        try:
            Path("/proc/sys/vm/drop_caches").write_text("3\n")
        except OSError as error:
            raise SystemExit(f"--drop-caches needs root on Linux ({error.strerror})") from None
    flag = "on" if warm_up else "off"
    out = subprocess.run(
        [sys.executable, __file__, "--child", flag], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="fresh processes per setting")
    parser.add_argument(
        "--drop-caches", action="store_true", help="drop the page cache before each process"
    )
    parser.add_argument("--no-csv", action="store_true")
    parser.add_argument("--child", choices=("on", "off"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child == "on")
        return
    if args.runs < 1:
        raise SystemExit("--runs must be >= 1")
    results: dict[str, list[dict]] = {name: [] for name in SETTINGS}
    for _ in range(args.runs):  # the settings take turns
        for name in SETTINGS:
            results[name].append(measure(name == SETTINGS[0], args.drop_caches))
    first = {
        name: float(np.median([r["first_ms"] for r in runs])) for name, runs in results.items()
    }
    ratio = first[SETTINGS[1]] / first[SETTINGS[0]]
    for name, runs in results.items():
        longest = max(r["max_ms"] for r in runs)
        median = f"{first[name]:6.1f} ms (median of {args.runs})"
        print(f"{name:24s} first act {median}, longest {longest:6.1f} ms")
    print(f"first act: reference / default = {ratio:.1f}x")
    if not args.no_csv:
        row = {
            "policy": "residual-3views + depth shield, random escapes",
            "processes": args.runs,
            "page_cache_dropped": args.drop_caches,
            "first_ms": round(first[SETTINGS[0]], 2),
            "reference_first_ms": round(first[SETTINGS[1]], 2),
            "max_ms": round(max(r["max_ms"] for r in results[SETTINGS[0]]), 2),
            "reference_max_ms": round(max(r["max_ms"] for r in results[SETTINGS[1]]), 2),
            "ratio": round(ratio, 2),
        }
        print(f"wrote {write_csv('first_act', [row])}")


if __name__ == "__main__":
    main()
