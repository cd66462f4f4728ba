"""The escape rows' wrapper on the students shipped until session 24: does it need a strong
student?

`clamgen eval --depth-escapes` (`depth_planner.ESCAPES`: the hybrids' shield with the
unseen-space test, random escapes from stalls instead of the planner; chosen in session 31 on
the students shipped since session 24) on the earlier recipe's students, on the 200 + 200 test
tasks, once each, choosing nothing: 3 views seed 0 (the policy shipped until session 24,
`../ensemble/shipped_until_session24/residual-3views.pt`) and seeds 1 and 2 (its recipe trained
again, `runs/reseed/d3-seed{1,2}/policy.pt`, as `camera_hybrid_seeds.py`); 2 and 1 views seed 0
only (the other seeds' files are lost). Writes `escapes<V>_until24_seed<k>.json` here (skipped
when they exist), prints the rows over seeds beside the same students alone, writes
older_escapes.txt and the seed set older_escapes.json (with P(escapes > alone) for the report).

    python results/stage2/shield/older_escapes.py [--summarize-only]
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

from clamgen.experiments.aggregate import seed_summary, write_seed_set

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
TABLE2 = ROOT / "results" / "table2"
PINNED = ROOT / "results" / "stage2" / "ensemble" / "shipped_until_session24"
WORDS = {3: "3 RGBD views", 2: "2 RGBD views", 1: "1 RGBD view"}
SHIPPED = {3: "residual-3views", 2: "residual-2views", 1: "residual-1view"}
SEEDS = {3: (0, 1, 2), 2: (0,), 1: (0,)}
ALONE = {
    3: {
        0: TABLE2 / "distilled_fixed_3views.json",
        1: HERE / "student3_seed1r.json",
        2: HERE / "student3_seed2r.json",
    },
}
"""The 3-view students' own test rows, alone (seed 0 the shipped policy's)."""
FAMILIES = ("obstacles", "blocked")


def _policy(views: int, seed: int) -> Path:
    if seed == 0:
        return PINNED / f"{SHIPPED[views]}.pt"
    return ROOT / "runs" / "reseed" / f"d{views}-seed{seed}" / "policy.pt"


def _out(views: int, seed: int) -> Path:
    return HERE / f"escapes{views}_until24_seed{seed}"


def _name(views: int) -> str:
    return (
        f"CLAMGen, {WORDS[views]}, the recipe of `{SHIPPED[views]}` as shipped until session 24 "
        "+ depth shield with random escapes when stuck, no planner (ours)"
    )


def _evaluate(views: int, seed: int) -> None:
    out = _out(views, seed)
    if out.with_suffix(".json").is_file():
        return
    command = [sys.executable, "-m", "clamgen", "eval", "--table", "2"]
    command += ["--policy", str(_policy(views, seed).relative_to(ROOT)), "--depth-escapes"]
    command += ["--num-tasks", "200", "--name", _name(views), "--out", str(out.relative_to(ROOT))]
    print("$", shlex.join(command), flush=True)
    subprocess.run(command, check=True, cwd=ROOT)


def seed_rows() -> dict[str, list[tuple[int, Path]]]:
    rows = {}
    for views, seeds in SEEDS.items():
        found = [(seed, _out(views, seed).with_suffix(".json")) for seed in seeds]
        rows[_name(views)] = [(seed, path) for seed, path in found if path.is_file()]
    alone = f"CLAMGen, 3 RGBD views, the recipe of `{SHIPPED[3]}` as shipped until session 24"
    alone += " (ours), alone"
    rows[alone] = sorted(ALONE[3].items())
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--summarize-only", action="store_true", help="evaluate nothing")
    args = parser.parse_args()
    if not args.summarize_only:
        for views, seeds in SEEDS.items():
            for seed in seeds:
                _evaluate(views, seed)
    rows = seed_rows()
    text = seed_summary(rows, FAMILIES)
    print(text)
    (HERE / "older_escapes.txt").write_text(text + "\n")
    alone = next(name for name in rows if name.endswith(", alone"))
    note = (
        "seed 0 is the policy shipped until session 24; 3-view seeds 1 and 2 its recipe trained "
        "again (runs/reseed/), as camera_hybrid_seeds.json"
    )
    command = "python results/stage2/shield/older_escapes.py --summarize-only"
    write_seed_set(rows, HERE / "older_escapes.json", command, note, [(_name(3), alone)])


if __name__ == "__main__":
    main()
