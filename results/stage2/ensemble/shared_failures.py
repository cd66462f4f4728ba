"""Which blocked tasks do all three 3-view seeds fail? Task geometry by outcome (a diagnosis).

The three seeds of the 3-view recipe fail 19 of block 170000's 300 blocked validation tasks
together (`ensemble_170000.jsonl`, README "The mean of the three 3-view seeds"). This resets
each of those tasks without rendering and compares their geometry with the tasks all three
solve: how close the target and the start tip are to the nearest obstacle surface, how
small the obstacles are, and how far the target is from the arm's base. Per group it prints
the median and quartiles and the Mann-Whitney U test's P (two-sided). Then, for every policy
on the block, its blocked success on the tasks whose target lies within `--near-m` of an
obstacle and on the others, with Wilson 95% intervals. Chooses nothing.

With `--trace POLICY ...` (names of `ensemble.py`), each policy runs again on the blocked
tasks it failed on the block (the evaluations are deterministic: the same episodes) and
every failure is told apart by where it happened: the step of the first collision and the
tip's distance to the target then, and the closest approach to the target; then a summary per
kind (collided on the first steps / collided near the target / collided elsewhere / stalled
near the target / stalled elsewhere), near and other tasks apart. With `--takeover-at N`,
each failure that stalled runs again for N steps of the policy and then the students' teacher
with its lookahead (fixed library of plans, as the students' runs; true poses, the simulator)
drives from that state to the end: can the stall be left at all, and how hard does the
teacher's first action command the joints there (largest |action| of 1) against the policy's?

    python results/stage2/ensemble/shared_failures.py [--block ensemble_170000.jsonl]
        [--trace 3v-s7] [--takeover-at 60]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from ensemble import load  # (this directory: the script's own)
from scipy.stats import mannwhitneyu

from clamgen.envs import ReachEnv
from clamgen.experiments.distill import target_clearance_m
from clamgen.experiments.tables import wilson_interval

HERE = Path(__file__).resolve().parent
SEEDS = ("3v-s5", "3v-s7", "3v-s8")
EARLY_STEPS = 2  # a first collision this early: the first action already runs into it
TEACHER = str(HERE.parent / "distill" / "teacher" / "policy.pt")  # the students' teacher
CLOSE_M = 0.04  # within this of the target (twice the success radius): "near the target"


def _rate(success: np.ndarray) -> str:
    low, high = wilson_interval(int(success.sum()), len(success))
    return f"{success.mean():.3f} ({low:.3f}-{high:.3f})"


def _clearance(point: np.ndarray, obstacles: np.ndarray) -> float:
    return float(target_clearance_m(point[None], obstacles[None])[0])


def geometry(seeds: list[int]) -> dict[int, dict[str, float]]:
    """Each blocked task's geometry, from one env reset per task (nothing rendered)."""
    env = ReachEnv(num_obstacles=2, task_family="blocked", include_obstacle_state=True)
    out = {}
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        obstacles, tip, goal = obs["obstacles"], obs["achieved_goal"], obs["desired_goal"]
        out[seed] = {
            "target to obstacle (m)": _clearance(goal, obstacles),
            "start tip to obstacle (m)": _clearance(tip, obstacles),
            "smallest half size (m)": float(obstacles[:, 5:8].min()),
            "start tip to target (m)": float(np.linalg.norm(goal - tip)),
            "target to base, horizontal (m)": float(np.linalg.norm(goal[:2])),
            "target height (m)": float(goal[2]),
        }
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--block", type=Path, default=HERE / "ensemble_170000.jsonl")
    parser.add_argument("--near-m", type=float, default=0.02, help="a target this close is near")
    parser.add_argument(
        "--trace", nargs="*", default=[], metavar="POLICY", help="where each failure happened"
    )
    parser.add_argument(
        "--takeover-at",
        type=int,
        default=None,
        metavar="N",
        help="with --trace: the lookahead teacher drives each stalled failure from step N on",
    )
    args = parser.parse_args()
    lines = [json.loads(line) for line in args.block.read_text().splitlines() if line]
    by = {x["policy"]: x for x in lines if x["family"] == "blocked"}
    seeds = next(iter(by.values()))["seeds"]
    tasks = geometry(seeds)
    if all(name in by for name in SEEDS):
        compare_geometry(by, tasks)
    near = np.array([tasks[s]["target to obstacle (m)"] < args.near_m for s in seeds])
    print(f"{near.sum()} of {len(seeds)} blocked tasks have their target within {args.near_m} m")
    for name, line in by.items():
        if line["seeds"] == seeds:
            won = np.array(line["success"])
            print(f"{name:24s} near {_rate(won[near])}, the others {_rate(won[~near])}")
    for name in args.trace:
        if name not in by or by[name]["seeds"] != seeds:
            raise SystemExit(f"{args.block} has no blocked line of {name} on these tasks")
        failed = [s for s, won in zip(seeds, by[name]["success"], strict=True) if not won]
        near_of = {s: bool(tasks[s]["target to obstacle (m)"] < args.near_m) for s in seeds}
        trace(name, failed, near_of, args.takeover_at)


def compare_geometry(by: dict[str, dict], tasks: dict[int, dict[str, float]]) -> None:
    """The geometry of the tasks every one of SEEDS fails against those they all solve."""
    success = np.array([by[name]["success"] for name in SEEDS])
    seeds = np.array(by[SEEDS[0]]["seeds"])
    groups = {"all fail": seeds[~success.any(0)], "all solve": seeds[success.all(0)]}
    features = {name: [tasks[int(s)] for s in group] for name, group in groups.items()}
    print(", ".join(f"{name}: {len(group)} tasks" for name, group in groups.items()))
    for key in features["all fail"][0]:
        values = {name: np.array([f[key] for f in rows]) for name, rows in features.items()}
        p = mannwhitneyu(values["all fail"], values["all solve"]).pvalue
        text = "; ".join(
            f"{name} {np.median(v):.3f} ({np.quantile(v, 0.25):.3f}-{np.quantile(v, 0.75):.3f})"
            for name, v in values.items()
        )
        print(f"{key:32s} {text}; P = {p:.3f}")


def failure(policy, env, seed: int) -> dict:
    """One episode of `policy` on task `seed`: the step of the first collision and the tip's
    distance to the target then (None: none), the closest approach, the final distance."""
    obs, _ = env.reset(seed=seed)
    policy.reset(env)
    first, closest, step, done = None, np.inf, 0, False
    while not done:
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        step += 1
        distance = float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"]))
        closest = min(closest, distance)
        if info["collision"] and first is None:
            first = (step, distance)
        done = terminated or truncated
    return {"first_collision": first, "closest_m": closest, "final_m": distance}


def kind_of(record: dict) -> str:
    first = record["first_collision"]
    if first is None:
        return "stalled near the target" if record["closest_m"] < CLOSE_M else "stalled elsewhere"
    if first[0] <= EARLY_STEPS:
        return "collided on the first steps"
    return "collided near the target" if first[1] < CLOSE_M else "collided elsewhere"


def takeover(policy, teacher, env, seed: int, steps: int) -> dict:
    """`policy` drives task `seed` for `steps` steps, then `teacher` (a `LookaheadPolicy`) to
    the end: whether it arrived without a collision after the handover, and the largest joint
    command of each one's action at the handover."""
    obs, _ = env.reset(seed=seed)
    policy.reset(env)
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        if terminated or truncated:
            raise SystemExit(f"task {seed} ended before step {steps}: not a stall there")
    mine = float(np.abs(policy.act(obs)).max())
    teacher.reset(env)
    action = teacher.act(obs)
    first, collided, done = float(np.abs(action).max()), False, False
    while not done:
        obs, _, terminated, truncated, info = env.step(action)
        collided |= bool(info["collision"])
        done = terminated or truncated
        if not done:
            action = teacher.act(obs)
    return {"arrived": bool(info["is_success"]) and not collided, "policy": mine, "teacher": first}


def trace(name: str, failed: list[int], near: dict[int, bool], takeover_at: int | None) -> None:
    """Each of `name`'s failed tasks run again, and the kinds of failure counted; with
    `takeover_at`, the stalled ones handed to the lookahead teacher there."""
    import torch

    torch.set_num_threads(1)
    policy, kwargs = load(name)
    # (the obstacles' poses in the observation are for the teacher; the policy reads none)
    env = ReachEnv(
        num_obstacles=2, task_family="blocked", **kwargs | {"include_obstacle_state": True}
    )
    kinds: dict[str, list[bool]] = {}
    stalled = []
    print(f"{name}: {len(failed)} failed blocked tasks")
    for seed in failed:
        record = failure(policy, env, seed)
        kind = kind_of(record)
        kinds.setdefault(kind, []).append(near[seed])
        if kind.startswith("stalled"):
            stalled.append(seed)
        first = record["first_collision"]
        when = (
            "no collision"
            if first is None
            else f"first collision step {first[0]} at {first[1]:.3f} m"
        )
        where = "near " if near[seed] else "other"
        closest, final = record["closest_m"], record["final_m"]
        print(f"  {seed} {where} {when}; closest {closest:.3f} m, final {final:.3f} m: {kind}")
    for kind, nears in sorted(kinds.items()):
        print(f"  {kind:28s} {len(nears):3d} (near-target tasks {sum(nears)})")
    if takeover_at is not None and stalled:
        from clamgen.experiments.lookahead import LookaheadPolicy, LookaheadTeacher
        from clamgen.experiments.policies import load_policy

        agent = load_policy(TEACHER)[0].agent
        teacher = LookaheadPolicy(LookaheadTeacher(agent, 2, fixed_offsets=True))
        runs = [takeover(policy, teacher, env, seed, takeover_at) for seed in stalled]
        arrived = sum(run["arrived"] for run in runs)
        mine, its = (np.median([run[key] for run in runs]) for key in ("policy", "teacher"))
        print(
            f"  the lookahead teacher from step {takeover_at} of the {len(runs)} stalls: arrives "
            f"on {arrived}; largest joint command, median: the teacher's {its:.2f}, the "
            f"policy's {mine:.2f}"
        )
    env.close()


if __name__ == "__main__":
    main()
