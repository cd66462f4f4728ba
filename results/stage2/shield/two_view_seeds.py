"""The 2-view hybrid (depth shield + planner on the depth map when stuck) on more training
seeds of the shipped `residual-2views` recipe. Seed 0 is the shipped policy
(results/table2/planned_residual-2views.json); seeds 3 and 4 are the 2-view DAgger runs of
`results/sweeps/shipped-1view.toml` (the same recipe; its seeds 1 and 2 were not kept), each
evaluated once on the 200 + 200 test tasks with the 2-view hybrid as it was then
(`clamgen eval --depth-shield-m 0.01 --depth-planner`, the shield on the 64-pixel views; the
hybrid reads 128-pixel depth cameras since session 18), choosing nothing
(planned2_seed<k>.json here; skipped when it exists). Prints, per task family, the mean
success with rliable's 95% stratified-bootstrap interval and each seed's success and
collision rate, and writes them to two_view_seeds.txt; the seed set two_view_seeds.json lets
`clamgen report` aggregate the row over the seeds.

    clamgen sweep results/sweeps/shipped-1view.toml --max-concurrent 1   # the DAgger runs
    python results/stage2/shield/two_view_seeds.py [--summarize-only]
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
RUNS = ROOT / "runs/sweeps/shipped-1view"
RUN = "clamgen-2-rgbd-views-distilled-from-the-lookahead-teacher-with-3-cm-clearance-ours"
SEEDS = (3, 4)
FAMILIES = ("obstacles", "blocked")
NAME = (  # the seeds' row name in their files
    "CLAMGen, 2 RGBD views, shipped `residual-2views` + depth shield + planner on the depth map "
    "when stuck (ours)"
)


HYBRID_THEN = ("--depth-shield-m", "0.01", "--depth-planner")
"""The 2-view hybrid these seeds were evaluated with."""


def _evaluate(seed: int) -> None:
    out = HERE / f"planned2_seed{seed}"
    if out.with_suffix(".json").is_file():
        return
    policy = RUNS / RUN / f"seed{seed}" / "policy.pt"
    if not policy.is_file():
        raise SystemExit(f"{policy} is not trained yet: run the shipped-1view sweep first")
    command = [sys.executable, "-m", "clamgen", "eval", "--table", "2"]
    command += ["--policy", str(policy), *HYBRID_THEN]
    command += ["--num-tasks", "200", "--name", NAME, "--out", str(out)]
    print("$", shlex.join(command), flush=True)
    subprocess.run(command, check=True)


def seed_rows() -> dict[str, list[tuple[int, Path]]]:
    """The hybrid's row (the shipped policy's name) and its seeds' test row JSONs, seed 0 first."""
    shipped = TABLE2 / "planned_residual-2views.json"
    found = [(seed, HERE / f"planned2_seed{seed}.json") for seed in SEEDS]
    return {table2_row_name(shipped): [(0, shipped)] + [(s, p) for s, p in found if p.is_file()]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--summarize-only", action="store_true", help="evaluate nothing")
    args = parser.parse_args()
    if not args.summarize_only:
        for seed in SEEDS:
            _evaluate(seed)
    rows = seed_rows()
    text = seed_summary(rows, FAMILIES)
    print(text)
    (HERE / "two_view_seeds.txt").write_text(text + "\n")
    command = "python results/stage2/shield/two_view_seeds.py --summarize-only"
    note = (
        "seed 0 is the policy shipped until session 24; seeds 3 and 4 the shipped-1view "
        "sweep's 2-view runs"
    )
    write_seed_set(rows, HERE / "two_view_seeds.json", command, note)


if __name__ == "__main__":
    main()
