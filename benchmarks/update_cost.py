"""Time of one stage-2 update (`ResidualAgent.update`) for each speed option, against the
paper-faithful fp32 update measured in the same run.

    python benchmarks/update_cost.py [--preset residual-cpu] [--updates 40] [--repeats 3]
        [--threads 1] [--device cpu] [--baseline-rev REV] [--no-csv]

Every row builds the agent of the preset (default `residual-cpu`: 2 views, 56 px crops of
64 px renders, batch 64) on the shipped base policy, warms it up, then times `--updates`
updates on fixed random batches, best of `--repeats` passes (the rows take turns pass by
pass, so other load falls on all of them alike). With `--baseline-rev REV` the first row
is the same preset's update in the code at git revision REV (run from `git archive` in a
subprocess), and every ratio is against it. `--device cuda` times the updates on a GPU (each
pass ends with a synchronisation, so the time is the GPU's). Rows:

- code at REV: the update before the rebuild (fp32, NCHW convs in chunks of 32);
- fp32, previous conv layout: today's code (each view's projection once per pass, faster
  crops) with the old layout;
- fp32: today's default, channels-last convs (same maths up to float rounding);
- bf16: the convs under bf16 autocast (`agent.encoder.bf16_autocast`); numbers change;
- online-encoder target: the target critic reads the online encoder's no-grad features of s',
  as in DrQ-v2 (`agent.target_encoder=online`), one conv pass fewer; numbers change;
- both.

Writes results/benchmarks/update_cost.csv unless --no-csv.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

from clamgen.agents.residual import ResidualAgent
from clamgen.experiments.config import load_preset
from clamgen.experiments.policies import resolve_policy_path
from clamgen.experiments.stage2 import Stage2Config
from clamgen.experiments.train import load_policy_agent

OPTIONS: dict[str, dict] = {
    "fp32, previous conv layout (NCHW, chunks of 32)": {
        "encoder": {"channels_last": False, "cpu_conv_chunk": 32}
    },
    "fp32 (paper-faithful target encoder)": {},
    "bf16 autocast of the convs": {"encoder": {"bf16_autocast": True}},
    "online-encoder target (DrQ-v2)": {"target_encoder": "online"},
    "bf16 + online-encoder target": {
        "target_encoder": "online",
        "encoder": {"bf16_autocast": True},
    },
}
"""Rows: agent-config overrides on top of the preset (`encoder` overrides the encoder's)."""


def with_options(agent_config, options: dict):
    options = dict(options)
    encoder = dataclasses.replace(agent_config.encoder, **options.pop("encoder", {}))
    return dataclasses.replace(agent_config, encoder=encoder, **options)


def random_batch(config: Stage2Config, size: int, rng: np.random.Generator) -> dict:
    """A replay-like batch: random images of the stored size, joints, goals, actions."""
    side, views = config.env.image_size, config.env.num_views

    def obs() -> dict[str, np.ndarray]:
        return {
            "observation": rng.uniform(-2, 2, (size, 6)).astype(np.float32),
            "desired_goal": rng.uniform(0.2, 0.6, (size, 3)).astype(np.float32),
            "achieved_goal": rng.uniform(0.2, 0.6, (size, 3)).astype(np.float32),
            "images": rng.integers(0, 256, (size, views, 4, side, side), dtype=np.uint8),
        }

    return {
        "obs": obs(),
        "next_obs": obs(),
        "action": rng.uniform(-1, 1, (size, 6)).astype(np.float32),
        "reward": np.full(size, -0.01, np.float32),
        "done": np.zeros(size, np.float32),
        "collision": (rng.random(size) < 0.1).astype(np.float32),
    }


def _synchronize(device: str) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def time_updates(
    agents: dict[str, ResidualAgent], batches: list[dict], repeats: int, device: str = "cpu"
):
    """Best mean seconds per update of each agent over `repeats` passes through `batches`.
    The agents take turns pass by pass, so load from other processes falls on all alike."""
    for agent in agents.values():
        for batch in batches[:3]:  # warm-up: allocator, oneDNN / cuDNN kernel selection
            agent.update(batch)
    best = dict.fromkeys(agents, float("inf"))
    for _ in range(repeats):
        for name, agent in agents.items():
            _synchronize(device)
            start = time.perf_counter()
            for batch in batches:
                agent.update(batch)
            _synchronize(device)
            best[name] = min(best[name], (time.perf_counter() - start) / len(batches))
    return best


def time_preset(
    preset: str,
    updates: int,
    repeats: int,
    options: dict[str, dict] | None,
    device: str = "cpu",
):
    """Seconds per update of the preset's agent on `device` with each of `options` (by row
    name; None: the preset as it is, which is all that code from another revision
    understands)."""
    config: Stage2Config = load_preset(preset, Stage2Config)
    base, _ = load_policy_agent(resolve_policy_path(config.base_policy))
    rng = np.random.default_rng(0)
    batches = [random_batch(config, config.agent.batch_size, rng) for _ in range(updates)]
    rows = {"preset": {}} if options is None else options
    agents = {
        name: ResidualAgent(
            dataclasses.replace(with_options(config.agent, row), device=device), base
        )
        for name, row in rows.items()
    }
    return time_updates(agents, batches, repeats, device)


def time_revision(rev: str, args) -> float:
    """The preset's update at git revision `rev` (its own src/), in a subprocess."""
    repo = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(
            ["git", "-C", str(repo), "archive", rev, "src"], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        env = dict(os.environ, PYTHONPATH=str(Path(tmp) / "src"))
        command = [sys.executable, __file__, "--plain", "--preset", args.preset]
        command += ["--updates", str(args.updates), "--repeats", str(args.repeats)]
        command += ["--threads", str(args.threads), "--device", args.device]
        out = subprocess.run(command, env=env, check=True, capture_output=True, text=True)
    return float(out.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="residual-cpu")
    parser.add_argument("--updates", type=int, default=40, help="updates per timed pass")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--device", default="cpu", help="torch device of the agents (cpu, cuda)")
    parser.add_argument(
        "--baseline-rev",
        default=None,
        help="also time the preset at this git revision (e.g. the commit before the rebuild), "
        "and make it the reference",
    )
    parser.add_argument("--plain", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--no-csv", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    if args.plain:  # the subprocess of time_revision: print seconds per update only
        print(time_preset(args.preset, args.updates, args.repeats, None, args.device)["preset"])
        return
    config: Stage2Config = load_preset(args.preset, Stage2Config)
    print(
        f"{args.preset}: batch {config.agent.batch_size}, {config.env.num_views} views, "
        f"{config.agent.encoder.image_size} px crops, {args.threads} torch thread(s), "
        f"device {args.device}"
    )
    load_before = os.getloadavg()[0]
    timings = {}
    if args.baseline_rev:  # before and after the rows, the better of the two
        timings[f"code at {args.baseline_rev} (fp32)"] = time_revision(args.baseline_rev, args)
    timings |= time_preset(args.preset, args.updates, args.repeats, OPTIONS, args.device)
    if args.baseline_rev:
        name = f"code at {args.baseline_rev} (fp32)"
        timings[name] = min(timings[name], time_revision(args.baseline_rev, args))
    reference = next(iter(timings.values()))
    rows = []
    for name, seconds in timings.items():
        rows.append(
            {
                "option": name,
                "preset": args.preset,
                "batch": config.agent.batch_size,
                "threads": args.threads,
                "device": args.device,
                "ms_per_update": round(1e3 * seconds, 2),
                "speedup_vs_reference": round(reference / seconds, 2),
                # Other load on the machine (1-min load average, before and after the rows):
                # absolute times grow with it, the ratios much less.
                "load_average": f"{load_before:.1f}-{os.getloadavg()[0]:.1f}",
            }
        )
        print(f"  {name:50s} {1e3 * seconds:7.1f} ms/update   x{reference / seconds:.2f}")
    print(f"reference: the first row ({rows[0]['option']}); load average {rows[0]['load_average']}")
    if not args.no_csv:
        print("wrote", write_csv("update_cost", rows))


if __name__ == "__main__":
    main()
