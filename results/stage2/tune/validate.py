"""Score training runs on validation tasks (never test tasks) to choose a recipe.

    python results/stage2/tune/validate.py runs/tune/priv-early/policy.pt ... --num-tasks 100

Each policy runs on `--num-tasks` blocked-path and standard obstacle tasks with validation seeds
(VALIDATION_SEEDS.start + VALIDATION_OFFSET + i: past the 50 that training's periodic
evaluation uses). Prints one line per policy and family and appends them to validation.jsonl,
with each task's outcome (lines from before session 38 have only the rates).

    python results/stage2/tune/validate.py --paired priv-least-s1 priv-fixed-s1 \
        --paired priv-least-s2 priv-fixed-s2

compares policies already scored on the same tasks (by label or source, the latest line of
each per family and block), task by task: how many tasks only one of them solves, with the
exact sign test's P, per pair and summed over the pairs.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from clamgen.envs import ReachEnv
from clamgen.experiments import lookahead
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.evaluate import evaluate, per_task
from clamgen.experiments.lookahead import LookaheadPolicy, LookaheadTeacher
from clamgen.experiments.policies import load_policy, policy_label
from clamgen.experiments.shield import load_shielded_student
from clamgen.experiments.tables import paired_count, wilson_interval

VALIDATION_OFFSET = 10_000
OUT = Path(__file__).with_name("validation.jsonl")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policies", nargs="*")
    parser.add_argument(
        "--paired",
        nargs=2,
        action="append",
        metavar=("FIRST", "SECOND"),
        help="compare two policies' lines in validation.jsonl task by task instead of scoring "
        "(repeat for several pairs; the totals sum them)",
    )
    parser.add_argument("--num-tasks", type=int, default=100)
    parser.add_argument("--families", nargs="+", default=["blocked", "obstacles"])
    parser.add_argument(
        "--offset",
        type=int,
        default=VALIDATION_OFFSET,
        help="task i has validation seed VALIDATION_SEEDS.start + offset + i (a fresh block for "
        "a new choice: 20000 for the session-15 1-view shield choice)",
    )
    parser.add_argument(
        "--stochastic", action="store_true", help="sample actions instead of the mean"
    )
    parser.add_argument(
        "--critic-candidates",
        type=int,
        default=0,
        help="act by the critic's best of this many candidate actions (0: the policy's mean)",
    )
    parser.add_argument(
        "--lookahead",
        type=int,
        default=0,
        help="plan with this many candidate rollouts in the simulator before each step "
        "(clamgen.experiments.lookahead; privileged policies only; 0: off)",
    )
    parser.add_argument("--lookahead-horizon", type=int, default=lookahead.HORIZON)
    parser.add_argument("--lookahead-noise", type=float, default=lookahead.NOISE)
    parser.add_argument(
        "--lookahead-margin",
        type=float,
        default=lookahead.MARGIN_M,
        help="clearance (m) the lookahead's plans keep where they can (0: true contact)",
    )
    parser.add_argument(
        "--lookahead-fixed-offsets",
        action="store_true",
        help="the lookahead's searches draw from one fixed library of perturbed plans",
    )
    parser.add_argument(
        "--clearance",
        type=float,
        default=0.0,
        help="score with envs that count approaches within this many metres of an obstacle or "
        "the table as collisions (0: true contact, as the tables)",
    )
    parser.add_argument(
        "--shield",
        type=float,
        default=None,
        metavar="MARGIN_M",
        help="the policies are distillation run directories: act through the collision shield "
        "on the obstacles the student's pose head reads (clamgen.experiments.shield), keeping "
        "this clearance",
    )
    parser.add_argument(
        "--shield-true-poses",
        action="store_true",
        help="the shield reads the true obstacle poses instead (an oracle)",
    )
    parser.add_argument(
        "--depth-shield",
        type=float,
        default=None,
        metavar="MARGIN_M",
        help="act through the collision shield on the policy's own depth images "
        "(clamgen.experiments.depth_shield), keeping this clearance",
    )
    parser.add_argument(
        "--depth-planner",
        action="store_true",
        help="with --depth-shield: plan on the depth map when the policy is stuck "
        "(clamgen.experiments.depth_planner)",
    )
    parser.add_argument(
        "--extrude",
        type=float,
        default=0.0,
        metavar="M",
        help="with --depth-shield: take the hidden side of each seen surface as filled this deep",
    )
    parser.add_argument(
        "--plan-margin",
        type=float,
        default=None,
        metavar="M",
        help="with --depth-planner: the clearance its paths keep (default: the shield's)",
    )
    parser.add_argument(
        "--shadow",
        type=float,
        default=None,
        metavar="M",
        help="with --depth-shield: the hand keeps out of the space the arm has hidden from "
        "the cameras since the episode began within M of seen obstacle surface "
        "(depth_shield.ArmShadow)",
    )
    parser.add_argument(
        "--shadow-behind-surfaces",
        action="store_true",
        help="with --shadow: space behind any seen surface counts as hidden, not only "
        "behind the arm",
    )
    parser.add_argument(
        "--bridge",
        type=float,
        default=0.0,
        metavar="M",
        help="with --depth-shield: neighbouring pixels' obstacle points up to M apart are "
        "joined by surface (DepthOccupancy's bridge_m)",
    )
    parser.add_argument(
        "--no-slide",
        action="store_true",
        help="the depth shield's alternatives leave out the slid action",
    )
    args = parser.parse_args()
    if args.paired:
        compare(args.paired)
        return
    if not args.policies:
        parser.error("name the policies to score, or --paired FIRST SECOND")
    torch.set_num_threads(1)
    for name in args.policies:
        if args.shield is not None:
            policy, env_kwargs = load_shielded_student(
                name, margin_m=args.shield, true_poses=args.shield_true_poses
            )
            source = str(name)
            label = f"{Path(name).name} (shield {args.shield} m"
            label += ", true poses)" if args.shield_true_poses else ")"
            if args.clearance:
                env_kwargs = {**env_kwargs, "collision_margin_m": args.clearance}
            score(policy, label, source, env_kwargs, args.num_tasks, args.families, args.offset)
            print(f"  shielded steps: {policy.num_shielded} of {policy.num_steps}")
            continue
        policy, source, env_kwargs = load_policy(name)
        if args.stochastic:
            policy.deterministic = False
        policy.critic_candidates = args.critic_candidates
        label = policy_label(name) + (" (stochastic)" if args.stochastic else "")
        if args.critic_candidates:
            label += f" (critic, {args.critic_candidates} candidates)"
        if args.lookahead:
            teacher = LookaheadTeacher(
                policy.agent,
                num_obstacles=2,
                candidates=args.lookahead,
                horizon=args.lookahead_horizon,
                noise=args.lookahead_noise,
                margin_m=args.lookahead_margin,
                fixed_offsets=args.lookahead_fixed_offsets,
            )
            policy = LookaheadPolicy(teacher)
            label += (
                f" (lookahead {args.lookahead} x {args.lookahead_horizon}, "
                f"noise {args.lookahead_noise}"
                + (f", margin {args.lookahead_margin} m" if args.lookahead_margin else "")
                + (", fixed library)" if args.lookahead_fixed_offsets else ")")
            )
        if args.depth_shield is not None and args.depth_planner:
            from clamgen.experiments.depth_planner import DepthShieldPlanner

            policy = DepthShieldPlanner(
                policy,
                env_kwargs["num_views"],
                env_kwargs["image_size"],
                args.depth_shield,
                extrude_m=args.extrude,
                plan_margin_m=args.plan_margin,
                shadow_m=args.shadow,
                shadow_behind_surfaces=args.shadow_behind_surfaces,
                bridge_m=args.bridge,
            )
            label += f" (depth shield {args.depth_shield} m + planner when stuck"
            if args.plan_margin is not None:
                label += f" keeping {args.plan_margin} m"
            label += f", extruded {args.extrude} m" if args.extrude else ""
            label += f", arm's shadow within {args.shadow} m kept out" if args.shadow else ""
            label += " (behind any surface)" if args.shadow_behind_surfaces else ""
            label += f", pixels bridged up to {args.bridge} m" if args.bridge else ""
            label += ")"
        elif args.depth_shield is not None:
            from clamgen.experiments.depth_shield import DepthShield

            policy = DepthShield(
                policy,
                env_kwargs["num_views"],
                env_kwargs["image_size"],
                args.depth_shield,
                sliding=not args.no_slide,
                extrude_m=args.extrude,
                shadow_m=args.shadow,
                shadow_behind_surfaces=args.shadow_behind_surfaces,
                bridge_m=args.bridge,
            )
            label += f" (depth shield {args.depth_shield} m" + ("" if args.no_slide else ", slide")
            label += f", extruded {args.extrude} m" if args.extrude else ""
            label += f", arm's shadow within {args.shadow} m kept out" if args.shadow else ""
            label += " (behind any surface)" if args.shadow_behind_surfaces else ""
            label += f", pixels bridged up to {args.bridge} m" if args.bridge else ""
            label += ")"
        if args.clearance:
            label += f" [scored with {args.clearance} m clearance]"
            env_kwargs = {**env_kwargs, "collision_margin_m": args.clearance}
        score(policy, label, source, env_kwargs, args.num_tasks, args.families, args.offset)
        if args.depth_shield is not None:
            print(f"  shielded steps: {policy.num_shielded} of {policy.num_steps}")
            if args.depth_planner:
                print(f"  plans: {policy.num_paths} found of {policy.num_plans}")


def score(
    policy,
    label,
    source,
    env_kwargs,
    num_tasks,
    families=("blocked", "obstacles"),
    offset=VALIDATION_OFFSET,
):
    """Run `policy` on `num_tasks` validation tasks of each family; print and append one line
    per family to validation.jsonl; {family: success}."""
    seeds = VALIDATION_SEEDS.seeds(num_tasks, VALIDATION_SEEDS.start + offset)
    scores = {}
    for family in families:
        tic = time.perf_counter()
        env = ReachEnv(num_obstacles=2, task_family=family, **env_kwargs)
        records = evaluate(env, policy, seeds)
        env.close()
        success = int(sum(r.success for r in records))
        low, high = wilson_interval(success, len(records))
        row = {
            "policy": label,
            "source": source,
            "family": family,
            "num_tasks": len(records),
            "first_seed": int(seeds[0]),
            "success": success / len(records),
            "ci95": [low, high],
            "collision": float(np.mean([r.collided for r in records])),
            "seconds": time.perf_counter() - tic,
        }
        outcomes = per_task(records)
        row["act_median_ms"] = outcomes.pop("act_median_ms")
        row["tasks"] = outcomes
        print(
            f"{label:28s} {family:9s} success {row['success']:.3f} "
            f"[{low:.2f}, {high:.2f}] collision {row['collision']:.3f} "
            f"({row['seconds']:.0f} s)",
            flush=True,
        )
        with OUT.open("a") as f:
            f.write(json.dumps(row) + "\n")
        scores[family] = row["success"]
    return scores


def compare(pairs: list[list[str]]) -> None:
    """Print, per family and block, how the pairs' per-task successes differ (validation.jsonl's
    latest line of each policy, matched by label or source), and the totals over the pairs."""
    latest = {}
    for line in OUT.read_text().splitlines():
        row = json.loads(line)
        if "tasks" in row:
            block = (row["family"], row["first_seed"], row["num_tasks"])
            latest[row["policy"], block] = latest[row["source"], block] = row
    unknown = {name for pair in pairs for name in pair} - {name for name, _ in latest}
    if unknown:
        raise SystemExit(
            f"no line of {OUT.name} with per-task outcomes names {', '.join(sorted(unknown))}"
        )
    for block in sorted({block for _, block in latest}):
        family, first_seed, num_tasks = block
        firsts, seconds = [], []
        for first, second in pairs:
            if (first, block) not in latest or (second, block) not in latest:
                continue
            a = latest[first, block]["tasks"]["success"]
            b = latest[second, block]["tasks"]["success"]
            count = paired_count(a, b)
            print(
                f"{family:9s} {num_tasks} tasks from {first_seed}: {first} {sum(a)}, {second} "
                f"{sum(b)}; only {first} {count.first_only}, only {second} "
                f"{count.second_only} (P = {count.p_value:.3f})"
            )
            firsts += a
            seconds += b
        if len(firsts) > num_tasks:
            count = paired_count(firsts, seconds)
            print(
                f"{family:9s} {num_tasks} tasks from {first_seed}, all pairs: {sum(firsts)} "
                f"against {sum(seconds)}; only the firsts {count.first_only}, only the seconds "
                f"{count.second_only} (P = {count.p_value:.3f})"
            )


if __name__ == "__main__":
    main()
