"""The hybrids in other settings on validation tasks, against the committed ones (protocols in
README.md, session 18): the planner's budget in validity checks instead of time (does the
deterministic budget keep success and collisions, and shorten the longest planning steps?),
and for 3 and 2 views the unseen-space test and the 128-pixel depth camera the 1-view hybrid
has (fewer collisions?).

    python results/stage2/shield/validate_hybrids.py --setting time     # the committed hybrids
    python results/stage2/shield/validate_hybrids.py --setting checks   # --depth-plan-checks 10000
    python results/stage2/shield/validate_hybrids.py --setting hidden --views 3 2
    python results/stage2/shield/validate_hybrids.py --setting fine --views 3 2
    python results/stage2/shield/validate_hybrids.py --setting hybrid          # session 20,
    python results/stage2/shield/validate_hybrids.py --setting hybrid-checks   # a fresh block
    python results/stage2/shield/validate_hybrids.py --setting hybrid-now      # session 41,
    python results/stage2/shield/validate_hybrids.py --setting escapes         # block 400000
    python results/stage2/shield/validate_hybrids.py --setting escapes-plan-0
    python results/stage2/shield/validate_hybrids.py --setting escapes-plan-1
    python results/stage2/shield/validate_hybrids.py --setting hybrid-410 --views 3 2
    python results/stage2/shield/validate_hybrids.py --setting hybrid-escapes --views 3 2

Each hybrid (`BEFORE[v]`, v = 3, 2, 1 views: `depth_planner.HYBRID` as it was before these
protocols, with the shipped policies; and its variants; the `hybrid*` settings start from
`HYBRID[v]` as it is now) acts on `--num-blocked` blocked and `--num-standard` standard
validation tasks from `--offset` into the validation range; the same tasks for every setting
of a block. Session 41 (block 400000): the hybrids and the escape rows as committed, and the
escape rows' shield with the planner too, planning only after 0 or 1 random escapes in the
episode (`DepthGuard(planner=True, escapes=True)`); then (block 410000) the 3- and 2-view
hybrids with random escapes where their planner finds no path. Appends one JSON line per
(views, family) to validate_hybrids_SETTING.jsonl (per task: success, collision, steps,
longest act; per run: the act time's median, 99th percentile and maximum, plans, escape steps)
and skips what is there; `--summary` prints the comparison from those files.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.depth_planner import ESCAPES, HYBRID, DepthGuard
from clamgen.experiments.evaluate import evaluate, per_task
from clamgen.experiments.machine import describe
from clamgen.experiments.policies import load_policy

HERE = Path(__file__).resolve().parent
PLAN_CHECKS = 10_000
"""About the time budget's 1 s of checks on the depth map on one core here (measured: 9,000-
12,000 checks a second, simplification and re-check included)."""
BEFORE = {3: DepthGuard(planner=True), 2: DepthGuard(planner=True), 1: HYBRID[1]}
"""The hybrids these protocols start from (session 17's `HYBRID`; session 18 gave the 3- and
2-view ones the 128-pixel depth camera, the "fine" setting here)."""
SETTINGS = {
    "time": lambda views: BEFORE[views],
    "checks": lambda views: replace(BEFORE[views], plan_checks=PLAN_CHECKS),
    # The 1-view hybrid's unseen-space test (`--depth-shadow-m 0.05
    # --depth-shadow-behind-surfaces`) for any number of views.
    "hidden": lambda views: replace(BEFORE[views], shadow_m=0.05, shadow_behind_surfaces=True),
    # The 1-view hybrid's 128-pixel depth camera (`--depth-fine-size 128`) for any number of
    # views.
    "fine": lambda views: replace(BEFORE[views], fine_depth_size=128),
    # Session 20, on a fresh block (--offset 50000): the hybrids as they are now, with the
    # planner's time budget and with the budget in checks.
    "hybrid": lambda views: HYBRID[views],
    "hybrid-checks": lambda views: replace(HYBRID[views], plan_checks=PLAN_CHECKS),
    # Session 41, on a fresh block (--offset 400000): the hybrids and the escape rows as they
    # are now, and the escape rows' shield with the planner after 0 or 1 escapes.
    "hybrid-now": lambda views: HYBRID[views],
    "escapes": lambda views: ESCAPES[views],
    "escapes-plan-0": lambda views: replace(ESCAPES[views], planner=True, escapes_before_plan=0),
    "escapes-plan-1": lambda views: replace(ESCAPES[views], planner=True, escapes_before_plan=1),
    # Session 41, second protocol (--offset 410000): the hybrids, and the hybrids with random
    # escapes where the planner finds no path (their own shield: no unseen-space test from 3
    # and 2 views).
    "hybrid-410": lambda views: HYBRID[views],
    "hybrid-escapes": lambda views: replace(HYBRID[views], escapes=True),
}
SESSION_41 = ("hybrid-now", "escapes", "escapes-plan-0", "escapes-plan-1")
OFFSET = (
    {"hybrid": 50_000, "hybrid-checks": 50_000}
    | {name: 400_000 for name in SESSION_41}
    | {"hybrid-410": 410_000, "hybrid-escapes": 410_000}
)
"""Where in the validation range each setting's tasks start (40000 for the others)."""
BASELINE = {
    "checks": "time",
    "hidden": "time",
    "fine": "time",
    "hybrid-checks": "hybrid",
    "escapes": "hybrid-now",
    "escapes-plan-0": "hybrid-now",
    "escapes-plan-1": "hybrid-now",
    "hybrid-escapes": "hybrid-410",
}
"""What each setting is compared with (on the same tasks)."""
POLICIES = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}


def out(setting: str) -> Path:
    return HERE / f"validate_hybrids_{setting}.jsonl"


def done() -> list[dict]:
    files = [out(setting) for setting in SETTINGS if out(setting).exists()]
    return [json.loads(line) for f in files for line in f.read_text().splitlines() if line]


def run(setting: str, views: int, family: str, seeds: list[int]) -> dict:
    guard = SETTINGS[setting](views)
    policy, _, env_kwargs = load_policy(POLICIES[views])
    hybrid, env_kwargs = guard.around(policy, env_kwargs)
    env = ReachEnv(num_obstacles=2, task_family=family, **env_kwargs)
    records = evaluate(env, hybrid, seeds)
    env.close()
    acts = np.concatenate([r.act_times_s for r in records]) * 1e3
    return {
        "setting": setting,
        "views": views,
        "family": family,
        "flags": list(guard.flags()),
        "seeds": seeds,
        **per_task(records),
        "longest_act_ms": [float(max(r.act_times_s) * 1e3) for r in records],
        "act_p99_ms": float(np.percentile(acts, 99)),
        "act_max_ms": float(acts.max()),
        "plans": int(getattr(hybrid, "num_plans", 0)),
        "paths": int(getattr(hybrid, "num_paths", 0)),
        "escape_steps": int(getattr(hybrid.policy, "num_burst_steps", 0)),
        "machine": describe(),
    }


def summary(lines: list[dict]) -> None:
    by = {(line["setting"], line["views"], line["family"]): line for line in lines}
    for views in (3, 2, 1):
        for family in ("blocked", "obstacles"):
            cells = []
            for setting in SETTINGS:
                line = by.get((setting, views, family))
                if line is None:
                    continue
                committed = by.get((BASELINE.get(setting), views, family))
                cell = (
                    f"{setting}: success {np.mean(line['success']):.3f} "
                    f"collisions {np.mean(line['collided']):.3f} "
                    f"act median {line['act_median_ms']:.2f} ms p99 {line['act_p99_ms']:.0f} ms "
                    f"max {line['act_max_ms'] / 1e3:.2f} s, {line.get('plans', '-')} plans"
                )
                if committed is not None:
                    same = np.mean(np.equal(committed["success"], line["success"]))
                    cell += (
                        f" (same outcome as {BASELINE[setting]} on {same:.3f} of "
                        f"{len(line['success'])})"
                    )
                cells.append(cell)
            print(f"{views} view(s), {family}: " + "; ".join(cells or ["-"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setting", choices=tuple(SETTINGS), default="time")
    parser.add_argument("--views", type=int, nargs="+", default=[3, 2, 1])
    parser.add_argument("--num-blocked", type=int, default=300)
    parser.add_argument("--num-standard", type=int, default=100)
    parser.add_argument(
        "--offset",
        type=int,
        default=None,
        help="default: 50000 for hybrid and hybrid-checks, 400000 and 410000 for session 41's, "
        "else 40000",
    )
    parser.add_argument("--summary", action="store_true", help="only print the comparison")
    args = parser.parse_args()
    if not args.summary:
        torch.set_num_threads(1)
        offset = OFFSET.get(args.setting, 40_000) if args.offset is None else args.offset
        first = VALIDATION_SEEDS.start + offset
        counts = {"blocked": args.num_blocked, "obstacles": args.num_standard}
        for views in args.views:
            for family, count in counts.items():
                if any(
                    (line["setting"], line["views"], line["family"])
                    == (args.setting, views, family)
                    for line in done()
                ):
                    continue
                seeds = [int(s) for s in VALIDATION_SEEDS.seeds(count, first)]
                line = run(args.setting, views, family, seeds)
                with out(args.setting).open("a") as f:
                    f.write(json.dumps(line) + "\n")
                print(f"{args.setting}, {views} view(s), {family}: done", flush=True)
    summary(done())


if __name__ == "__main__":
    main()
