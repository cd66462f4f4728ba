"""The shipped `residual-1view` recipe over several training seeds, alone and as the 1-view
hybrid (depth shield keeping the hand out of unseen space behind seen surfaces, planner on the
depth map when stuck).

    clamgen sweep results/sweeps/shipped-1view.toml --max-concurrent 1   # the DAgger runs
    python results/stage2/distill/shipped_1view_seeds.py                  # the rest

Seed 0 is the shipped student (results/table2/distilled_pooled_1view.json and
planned_hidden_residual-1view.json). Recipe seed k (1, 2, ...) regresses a fresh 1-view student
on the pooled data of the sweep's 1-view run of seed k and its 2-view run of seed k + 2
(`offline.py`, 24k updates, as for seed 0), into runs/offline/d1-pool12-seed<k>, and evaluates
it on the 200 + 200 test tasks alone and as the hybrid (shipped_1view/seed<k>_*.json; each
evaluation carries its row's name, that of the shipped seed-0 row it adds a seed to). Each step
is skipped when its output exists, so the script resumes. Last it prints, per row and task
family, the mean success over seeds with rliable's 95% stratified-bootstrap interval and each
seed's success and collision rate, and writes them to shipped_1view/seeds.txt; the seed set
shipped_1view/seeds.json lets `clamgen report` aggregate the rows over the seeds.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from clamgen.experiments.aggregate import seed_summary, table2_row_name, write_seed_set
from clamgen.experiments.depth_planner import HYBRID

HERE = Path(__file__).resolve().parent
OUT = HERE / "shipped_1view"
TABLE2 = HERE.parents[1] / "table2"
SWEEP = Path("runs/sweeps/shipped-1view")
RUN_1VIEW = "clamgen-1-rgbd-view-distilled-from-the-lookahead-teacher-with-3-cm-clearance-ours"
RUN_2VIEWS = "clamgen-2-rgbd-views-distilled-from-the-lookahead-teacher-with-3-cm-clearance-ours"
SECOND_SEED_OFFSET = 2
"""Recipe seed k pools the 1-view run of seed k with the 2-view run of seed k + 2."""
UPDATES = 24_000
FAMILIES = ("obstacles", "blocked")
HYBRID_64PX_FLAGS = replace(HYBRID[1], fine_depth_size=0).flags()  # session 14's 1-view hybrid
HYBRID_FLAGS = HYBRID[1].flags()  # the committed one: the shield reads a 128-px depth camera
ROWS = {
    "student": (
        "CLAMGen, 1 RGBD view, regressed on the pooled data of the 1- and 2-view clearance "
        "students (ours)",
        (),
        "distilled_pooled_1view.json",
    ),
    "hybrid": (
        "CLAMGen, 1 RGBD view, shipped `residual-1view` + depth shield keeping the hand out of "
        "unseen space behind seen surfaces + planner on the depth map when stuck (ours)",
        HYBRID_64PX_FLAGS,
        "planned_hidden_residual-1view.json",
    ),
    "hybrid-fine": (
        "CLAMGen, 1 RGBD view, shipped `residual-1view` + depth shield on a 128-pixel depth camera "
        "keeping the hand out of unseen space behind seen surfaces + planner on the depth map "
        "when stuck (ours)",
        HYBRID_FLAGS,
        "planned_hidden_fine_residual-1view.json",
    ),
}


def _run(command: list[str]) -> None:
    print("$", shlex.join(command), flush=True)
    subprocess.run(command, check=True)


def _student(seed: int) -> Path:
    out = Path(f"runs/offline/d1-pool12-seed{seed}")
    if (out / "policy.pt").is_file():
        return out
    first = SWEEP / RUN_1VIEW / f"seed{seed}"
    second = SWEEP / RUN_2VIEWS / f"seed{seed + SECOND_SEED_OFFSET}"
    for run in (first, second):
        if not (run / "policy.pt").is_file():
            raise SystemExit(f"{run} is not trained yet: run the shipped-1view sweep first")
    script = [sys.executable, str(HERE / "offline.py"), str(first), str(out)]
    _run([*script, "--updates", str(UPDATES), "--pool", str(second)])
    return out


def _evaluate(seed: int, student: Path) -> None:
    for key, (name, flags, _) in ROWS.items():
        out = OUT / f"seed{seed}_{key}"
        if out.with_suffix(".json").is_file():
            continue
        command = [sys.executable, "-m", "clamgen", "eval", "--table", "2"]
        command += ["--policy", str(student / "policy.pt")]
        _run([*command, *flags, "--num-tasks", "200", "--name", name, "--out", str(out)])


def seed_rows(seeds: list[int]) -> dict[str, list[tuple[int, Path]]]:
    """{row name (the shipped policy's): [(seed, its test row JSON), ...]}, seed 0 first."""
    rows = {}
    for key, (_, _, shipped) in ROWS.items():
        found = [(seed, OUT / f"seed{seed}_{key}.json") for seed in seeds]
        rows[table2_row_name(TABLE2 / shipped)] = [(0, TABLE2 / shipped)] + [
            (seed, path) for seed, path in found if path.is_file()
        ]
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--summarize-only", action="store_true", help="train and evaluate nothing")
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    if not args.summarize_only:
        for seed in args.seeds:
            _evaluate(seed, _student(seed))
    rows = seed_rows(args.seeds)
    text = seed_summary(rows, FAMILIES)
    print(text)
    (OUT / "seeds.txt").write_text(text + "\n")
    command = "python results/stage2/distill/shipped_1view_seeds.py --summarize-only"
    note = (
        "seed 0 is the policy shipped until session 24; seed k pools the 1-view run of seed k "
        "with the 2-view run of seed k + 2 of the shipped-1view sweep"
    )
    write_seed_set(rows, OUT / "seeds.json", command, note)


if __name__ == "__main__":
    main()
