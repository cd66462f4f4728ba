"""Two jobs at once on this machine's cores: evaluation episodes with numpy's BLAS on one thread
(the package default, `clamgen/__init__.py`) against as many threads as cores (OpenBLAS's own
default, the reference), measured in the same run.

Each job is a process of its own (`JOB`) that acts with the shipped
`residual-3views` on `--episodes` blocked-path tasks (rendering its views every step, as
evaluations and training do) and reports its wall time. Two such jobs start together, the
way two evaluations or training runs share the machine; then one job alone. The settings
take turns, `--repeats` times each. With `--training`, also two short stage-2 training runs at
once (`clamgen train-residual --preset residual-cpu`, `TRAINING_STEPS` env steps after
`TRAINING_STARTS`, each in a temporary run directory), timed whole, start-up included.

    python benchmarks/concurrent_jobs.py [--episodes 20] [--repeats 2] [--training] [--no-csv]

Prints each setting's median wall time per job, the ratio of the reference's to the
default's, and writes results/benchmarks/concurrent_jobs.csv unless --no-csv.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
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


TRAINING_STEPS = 1600
TRAINING_STARTS = 400
TRAIN = [
    *(sys.executable, "-m", "clamgen", "train-residual", "--preset", "residual-cpu"),
    *("--loop.total-env-steps", str(TRAINING_STEPS), "--loop.learning-starts"),
    *(str(TRAINING_STARTS), "--loop.eval-every-steps", "0"),
]
"""A short stage-2 training run (add `--run-dir`)."""


def run_jobs(count: int, extra_env: dict, episodes: int, training: bool = False) -> list[float]:
    """Start `count` jobs together; their wall times (s): an evaluation job's own timing of its
    episodes, a training run's whole process."""
    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    env |= extra_env | {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    with tempfile.TemporaryDirectory() as tmp:
        commands = [
            [*TRAIN, "--run-dir", f"{tmp}/run{i}"]
            if training
            else [sys.executable, "-c", JOB, str(FIRST_SEED), str(episodes)]
            for i in range(count)
        ]
        output = subprocess.DEVNULL if training else subprocess.PIPE  # (one line a job)
        start = time.perf_counter()
        jobs = [
            subprocess.Popen(command, env=env, stdout=output, stderr=subprocess.DEVNULL, text=True)
            for command in commands
        ]
        walls = [0.0] * count
        while not all(walls):  # each job's own finish, whichever ends first
            for i, job in enumerate(jobs):
                if not walls[i] and job.poll() is not None:
                    walls[i] = time.perf_counter() - start
            time.sleep(0.01)
        outputs = [job.communicate()[0] for job in jobs]
    if any(job.returncode for job in jobs):
        raise SystemExit("a job failed: run its command alone to see why")
    return walls if training else [float(out.split()[-1]) for out in outputs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--training", action="store_true", help="also two training runs")
    parser.add_argument("--no-csv", action="store_true")
    args = parser.parse_args()
    rows = []
    cases = [("evaluation", 2), ("evaluation", 1)] + ([("training", 2)] if args.training else [])
    for kind, count in cases:
        times: dict[str, list[float]] = {name: [] for name in SETTINGS}
        for _ in range(args.repeats):
            for name, extra in SETTINGS.items():
                times[name] += run_jobs(count, extra, args.episodes, kind == "training")
        default, reference = (float(np.median(t)) for t in times.values())
        for name, values in times.items():
            walls = ", ".join(f"{value:.2f}" for value in values)
            print(f"{kind}, {count} at once, {name}: {np.median(values):.2f} s a job ({walls})")
        print(f"  the reference takes x{reference / default:.2f} as long")
        rows.append(
            {
                "job": kind,
                "jobs_at_once": count,
                "episodes_per_job": args.episodes if kind == "evaluation" else "",
                "env_steps_per_job": TRAINING_STEPS if kind == "training" else "",
                "default_s": round(default, 2),
                "reference_s": round(reference, 2),
                "ratio": round(reference / default, 2),
            }
        )
    if not args.no_csv:
        print("wrote", write_csv("concurrent_jobs", rows))


if __name__ == "__main__":
    main()
