"""Two jobs at once on this machine's cores: evaluation episodes with numpy's BLAS on one thread
(the package default, `clamgen/__init__.py`) against as many threads as cores (OpenBLAS's own
default, the reference), measured in the same run.

Each job is a process of its own (`JOB`) that acts with the shipped
`residual-3views` on `--episodes` blocked-path tasks (rendering its views every step, as
evaluations and training do) and reports its wall time. Two such jobs start together, the
way two evaluations or training runs share the machine; then one job alone. The settings
take turns, `--repeats` times each.

    python benchmarks/concurrent_jobs.py [--episodes 20] [--repeats 2] [--no-csv]

Prints each setting's median wall time per job, the ratio of the reference's to the
default's, and writes results/benchmarks/concurrent_jobs.csv unless --no-csv.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

FIRST_SEED = 2_000_390_000  # validation seeds (`VALIDATION_SEEDS`), a block no choice used
SETTINGS = {
    "one BLAS thread (default)": {},
    "BLAS threads = cores (reference)": {"OPENBLAS_NUM_THREADS": str(os.cpu_count() or 1)},
}


JOB = """
import sys, time
import clamgen  # first, as on the command line, so that its BLAS default applies to numpy
import torch
from clamgen.envs import ReachEnv
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.policies import load_policy

first, episodes = int(sys.argv[1]), int(sys.argv[2])
torch.set_num_threads(1)
policy, _, env_kwargs = load_policy("residual-3views")
env = ReachEnv(num_obstacles=2, task_family="blocked", **env_kwargs)
start = time.perf_counter()
evaluate(env, policy, range(first, first + episodes))
print(time.perf_counter() - start)
"""
"""One job: act on blocked tasks from seed argv[1], argv[2] of them; print the wall time."""


def run_jobs(count: int, extra_env: dict, episodes: int) -> list[float]:
    """Start `count` jobs together; their wall times (s)."""
    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    env |= extra_env | {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    command = [sys.executable, "-c", JOB, str(FIRST_SEED), str(episodes)]
    jobs = [
        subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True) for _ in range(count)
    ]
    outputs = [p.communicate()[0] for p in jobs]
    if any(p.returncode for p in jobs):
        raise SystemExit("a job failed")
    return [float(out.split()[-1]) for out in outputs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-csv", action="store_true")
    args = parser.parse_args()
    rows = []
    for count in (2, 1):
        times: dict[str, list[float]] = {name: [] for name in SETTINGS}
        for _ in range(args.repeats):
            for name, extra in SETTINGS.items():
                times[name] += run_jobs(count, extra, args.episodes)
        default, reference = (float(np.median(t)) for t in times.values())
        for name, values in times.items():
            print(f"{count} job(s) at once, {name}: {np.median(values):.2f} s a job {values}")
        print(f"  the reference takes x{reference / default:.2f} as long")
        rows.append(
            {
                "jobs_at_once": count,
                "episodes_per_job": args.episodes,
                "default_s": round(default, 2),
                "reference_s": round(reference, 2),
                "ratio": round(reference / default, 2),
            }
        )
    if not args.no_csv:
        print("wrote", write_csv("concurrent_jobs", rows))


if __name__ == "__main__":
    main()
