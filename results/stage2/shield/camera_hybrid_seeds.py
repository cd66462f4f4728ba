"""The 3- and 2-view hybrids as they are now (`clamgen eval --depth-hybrid`: the depth shield
and the planner on 128-pixel depth cameras) on more training seeds of the shipped recipes.

Seed 0 is the shipped student (results/table2/planned_fine_residual-3views.json, -2views;
alone distilled_fixed_3views.json, distilled_clearance_2views.json).
The other seeds' students were trained again in runs/reseed/ from the commands of their
sweeps, none of whose policies this checkout keeps (a retrained run does not repeat the
earlier one bit for bit):

- 3 views, seeds 1 and 2: `results/sweeps/lookahead-fixed/summary.json` (policy.pt there is
  the iteration with the best success on the 100 per-iteration validation tasks);
- 2 views, seeds 3 and 4: `results/sweeps/shipped-1view/summary.json` (the same rule).

    clamgen distill <the run's train_command, with --run-dir runs/reseed/d<V>-seed<k>>

The 3-view seeds 1 and 2 (session 20) and the 2-view seed 4 (session 21) were retrained and
evaluated on an AVX2 CPU without bf16 in hardware, so their convs ran in float32 in training
and acting (the preset's bf16 autocast applies only where the CPU computes bf16;
`results/stage2/precision/`); seed 0 and the 2-view seed 3 ran on a CPU with it. Each eval
file records its `machine`.

Each student is evaluated once its run has finished, on the 200 + 200 test tasks, alone and as
the hybrid, choosing nothing (`student<V>_seed<k>r.json`, `planned<V>_fine_seed<k>r.json` here,
"r" for retrained; skipped when they exist). Prints, per number of views and task family, the
hybrid's mean success over seeds with rliable's 95% stratified-bootstrap interval and each
seed's success and collision rate (then the same for the students alone), and writes
camera_hybrid_seeds.txt; the seed set camera_hybrid_seeds.json lets `clamgen report` aggregate
the hybrid rows over the seeds (the students alone are rows of the sweeps named above).

    python results/stage2/shield/camera_hybrid_seeds.py [--views 3 2] [--seeds 1 2]
    python results/stage2/shield/camera_hybrid_seeds.py --summarize-only
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

from clamgen.experiments.aggregate import seed_summary, table2_row_name, write_seed_set

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
TABLE2 = ROOT / "results" / "table2"
SEEDS = {3: (1, 2), 2: (3, 4)}
FAMILIES = ("obstacles", "blocked")
WORDS = {3: "3 RGBD views", 2: "2 RGBD views"}
SHIPPED = {3: "residual-3views", 2: "residual-2views"}
SHIPPED_ALONE = {3: "distilled_fixed_3views.json", 2: "distilled_clearance_2views.json"}
"""The shipped students' own test rows (seed 0, alone)."""


def _hybrid_name(views: int) -> str:
    return (
        f"CLAMGen, {WORDS[views]}, shipped `{SHIPPED[views]}` + depth shield on 128-pixel depth "
        "cameras + planner on the depth map when stuck (ours)"
    )


def _student_name(views: int) -> str:
    return f"CLAMGen, {WORDS[views]}, student of the shipped `{SHIPPED[views]}` recipe (ours)"


def _out(views: int, seed: int, hybrid: bool) -> Path:
    return HERE / (f"planned{views}_fine_seed{seed}r" if hybrid else f"student{views}_seed{seed}r")


def _evaluate(views: int, seed: int) -> None:
    policy = ROOT / "runs" / "reseed" / f"d{views}-seed{seed}" / "policy.pt"
    for hybrid in (True, False):
        out = _out(views, seed, hybrid)
        if out.with_suffix(".json").is_file():
            continue
        name = _hybrid_name(views) if hybrid else _student_name(views)
        command = [sys.executable, "-m", "clamgen", "eval", "--table", "2", "--policy", str(policy)]
        command += ["--depth-hybrid"] if hybrid else []
        command += ["--num-tasks", "200", "--name", name, "--out", str(out)]
        print("$", shlex.join(command), flush=True)
        subprocess.run(command, check=True)


def seed_rows(views: int, hybrid: bool) -> dict[str, list[tuple[int, Path]]]:
    """{row name: [(seed, its test row JSON), ...]}, the shipped seed 0 first: the hybrid rows
    named as the shipped policy's, the students alone as the recipe's."""
    shipped = TABLE2 / (f"planned_fine_{SHIPPED[views]}.json" if hybrid else SHIPPED_ALONE[views])
    found = [(seed, _out(views, seed, hybrid).with_suffix(".json")) for seed in SEEDS[views]]
    alone = f"CLAMGen, {WORDS[views]}, the recipe of `{SHIPPED[views]}` as shipped until session 24"
    name = table2_row_name(shipped) if hybrid else alone + " (ours), alone"
    return {name: [(0, shipped)] + [(seed, path) for seed, path in found if path.is_file()]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, nargs="+", choices=(3, 2), default=[3, 2])
    parser.add_argument("--seeds", type=int, nargs="+", help="evaluate only these seeds")
    parser.add_argument("--summarize-only", action="store_true", help="evaluate nothing")
    args = parser.parse_args()
    if not args.summarize_only:
        for views in args.views:
            for seed in SEEDS[views]:
                if args.seeds and seed not in args.seeds:
                    continue
                done = ROOT / "runs" / "reseed" / f"d{views}-seed{seed}" / "summary.json"
                if done.is_file():  # (written when the run has finished)
                    _evaluate(views, seed)
    hybrids = {k: v for views in (3, 2) for k, v in seed_rows(views, True).items()}
    alone = {k: v for views in (3, 2) for k, v in seed_rows(views, False).items()}
    text = seed_summary(hybrids | alone, FAMILIES)
    print(text)
    (HERE / "camera_hybrid_seeds.txt").write_text(text + "\n")
    command = "python results/stage2/shield/camera_hybrid_seeds.py --summarize-only"
    note = (
        "seed 0 is the policy shipped until session 24; the others are its recipe trained "
        "again from the sweep's commands (runs/reseed/), not the sweep's own runs of that seed"
    )
    write_seed_set(hybrids, HERE / "camera_hybrid_seeds.json", command, note)


if __name__ == "__main__":
    main()
