"""The shipped vision policies acting in float32 against bf16 convs, on a CPU without bf16 in
hardware: same outcomes, task by task?

The students were trained and evaluated with their convs under bf16 autocast
(`EncoderConfig.bf16_autocast`) on CPUs that compute bf16 in hardware. On a CPU that emulates
it (AVX2 only), the encoder now runs its convs in float32 (`clamgen.agents.encoders.native_bf16`),
about 2.4x faster per act for 3 views. `--precision bf16` runs the emulated bf16 convs instead
(`CLAMGEN_EMULATED_BF16=1`, the numbers of the committed rows up to rounding), `--precision
fp32` the default here. Each shipped policy (alone, or with `--hybrid` as
`clamgen eval --depth-hybrid` acts) runs on `--num-blocked` blocked and `--num-standard`
standard validation tasks from `--offset` into the validation range, the same tasks for both
precisions; one JSON line per (precision, hybrid, views, family) goes to precision.jsonl
(per task: success, collision, steps; the run's median act), skipping what is there.
`--summary` prints the comparison.

    python results/stage2/precision/compare_precision.py --precision bf16 [--hybrid]
    python results/stage2/precision/compare_precision.py --precision fp32 [--hybrid]
    python results/stage2/precision/compare_precision.py --summary
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from clamgen.agents import encoders

HERE = Path(__file__).resolve().parent
OUT = HERE / "precision.jsonl"
POLICIES = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}
FAMILIES = ("blocked", "obstacles")


def done() -> list[dict]:
    if not OUT.exists():
        return []
    return [json.loads(line) for line in OUT.read_text().splitlines() if line]


def run(views: int, family: str, seeds: list[int], hybrid: bool) -> dict:
    import torch

    from clamgen.envs import ReachEnv
    from clamgen.experiments.depth_planner import HYBRID
    from clamgen.experiments.evaluate import evaluate, per_task
    from clamgen.experiments.policies import load_policy

    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy(POLICIES[views])
    extra = {}
    if hybrid:
        guard = HYBRID[views]
        policy = guard.wrap(policy, env_kwargs["num_views"], env_kwargs["image_size"])
        extra = guard.env_kwargs()
    env = ReachEnv(num_obstacles=2, task_family=family, **env_kwargs, **extra)
    records = evaluate(env, policy, seeds)
    env.close()
    return {"views": views, "family": family, "hybrid": hybrid, "seeds": seeds} | per_task(records)


def summary(lines: list[dict]) -> None:
    by = {(x["precision"], x["hybrid"], x["views"], x["family"]): x for x in lines}
    for hybrid in (False, True):
        for views in (3, 2, 1):
            for family in FAMILIES:
                a, b = (
                    by.get(("bf16", hybrid, views, family)),
                    by.get(("fp32", hybrid, views, family)),
                )
                if a is None or b is None:
                    continue
                same = np.equal(a["success"], b["success"]) & np.equal(a["collided"], b["collided"])
                print(
                    f"{'hybrid' if hybrid else 'alone'} {views} view(s) {family} "
                    f"({len(a['seeds'])} tasks): bf16 success {np.mean(a['success']):.3f} "
                    f"collisions {np.mean(a['collided']):.3f} act {a['act_median_ms']:.2f} ms; "
                    f"fp32 success {np.mean(b['success']):.3f} "
                    f"collisions {np.mean(b['collided']):.3f} act {b['act_median_ms']:.2f} ms; "
                    f"same outcome on {int(same.sum())} / {len(same)}"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--precision", choices=("bf16", "fp32"))
    parser.add_argument("--hybrid", action="store_true", help="as `clamgen eval --depth-hybrid`")
    parser.add_argument("--views", type=int, nargs="+", default=[3, 2, 1])
    parser.add_argument("--num-blocked", type=int, default=300)
    parser.add_argument("--num-standard", type=int, default=100)
    parser.add_argument("--offset", type=int, default=60_000)
    parser.add_argument("--summary", action="store_true", help="only print the comparison")
    args = parser.parse_args()
    if not args.summary:
        if args.precision is None:
            parser.error("--precision is required unless --summary")
        if args.precision == "bf16":
            os.environ[encoders.EMULATED_BF16_ENV] = "1"
        from clamgen.experiments.config import VALIDATION_SEEDS

        first = VALIDATION_SEEDS.start + args.offset
        counts = {"blocked": args.num_blocked, "obstacles": args.num_standard}
        for views in args.views:
            for family, count in counts.items():
                key = (args.precision, args.hybrid, views, family)
                if any(
                    (x["precision"], x["hybrid"], x["views"], x["family"]) == key for x in done()
                ):
                    continue
                seeds = [int(s) for s in VALIDATION_SEEDS.seeds(count, first)]
                line = {"precision": args.precision} | run(views, family, seeds, args.hybrid)
                with OUT.open("a") as f:
                    f.write(json.dumps(line) + "\n")
                print(f"{key}: done, success {np.mean(line['success']):.3f}", flush=True)
    summary(done())


if __name__ == "__main__":
    main()
