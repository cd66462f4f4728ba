"""Re-time the aims table's shipped-seed rows in their own evaluations on this machine.

    python results/benchmarks/act_latency_runs/retime_evals.py [--rows 3v-escapes ...] \
        --out results/benchmarks/act_latency_runs/retimed_<machine>

(`--rows 3v-hybrid-told-k0p01 ...`: the rows on noisy depth, `TOLD_ROWS`.)

Each row's committed Table 2 evaluation (the shipped students, seed 5) runs again with its own
command, one process at a time (run it with nothing else on the machine), into `--out`. The
act medians are this machine's, timed between rendered steps as `clamgen eval` times them; the
outcomes are compared with the committed rows task by task (the same on a machine whose convs
run in the same precision, and for the hybrids only where no plan ran out of time). Also the
blocked tasks' act tail here: the 99th percentile, the longest act and the share of acts over
the 2 ms aim (`ObstacleRow.act_share_over_aim`). Prints and writes `--out`/summary.md. A
shipped student evaluated from its run directory (since deleted) runs under its shipped name:
the same file.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

from clamgen.experiments.machine import describe

ROOT = Path(__file__).resolve().parents[3]
ROWS = {
    "3v-alone": ("results/stage2/ensemble/3v-dagger+2_test.json", "residual-3views"),
    "3v-shielded": ("results/table2/shielded_fine_residual-3views.json", None),
    "3v-escapes": ("results/table2/escapes_residual-3views.json", None),
    "3v-hybrid": ("results/table2/hybrid_residual-3views.json", None),
    "2v-alone": ("results/stage2/ensemble/2v-dagger+2_test.json", "residual-2views"),
    "2v-escapes": ("results/table2/escapes_residual-2views.json", None),
    "2v-hybrid": ("results/table2/hybrid_residual-2views.json", None),
    "1v-alone": ("results/stage2/ensemble/1v-dagger+2_test.json", "residual-1view"),
    "1v-escapes": ("results/table2/escapes_residual-1view.json", None),
    "1v-hybrid": ("results/table2/hybrid_residual-1view.json", None),
    "1v-escapes-planner": ("results/table2/escapes_planner_residual-1view.json", None),
}
"""Row: (its committed evaluation, the shipped name to act under where its command names a
run directory's policy file)."""
TOLD_ROWS = {
    f"{views[0]}v-{row}-told-k{level}": (
        f"results/stage2/noise/{row}-told-{views}-k{level}.json",
        None,
    )
    for level in ("0p003", "0p01")
    for row in ("hybrid", "escapes")
    for views in ("3views", "2views", "1view")
}
"""The same for the shipped seed's rows on noisy depth, the wrappers told the noise (session
47's `run_told.sh`; `--rows` names them, the default is the exact-depth rows above)."""


def command(committed: dict, policy: str | None, out: Path) -> list[str]:
    """The committed row's `clamgen eval` arguments, writing to `out` (and, with `policy`,
    acting under that name)."""
    args = shlex.split(committed["command"])[2:]  # after "clamgen eval"
    args[args.index("--out") + 1] = str(out)
    if policy is not None:
        args[args.index("--policy") + 1] = policy
    return [sys.executable, "-m", "clamgen", "eval", *args, "--overwrite"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", nargs="+", choices=[*ROWS, *TOLD_ROWS], default=list(ROWS))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [
        f"Machine: {describe()}.",
        "",
        "| row | blocked act ms: committed / here | standard act ms: committed / here "
        "| committed machine | tasks with another outcome (blocked, standard) "
        "| blocked act here: p99 ms / longest ms / share over 2 ms |",
        "|---|---|---|---|---|---|",
    ]
    for name in args.rows:
        path, policy = (ROWS | TOLD_ROWS)[name]
        committed = json.loads((ROOT / path).read_text())
        out = args.out / name
        run = command(committed, policy, out)
        print("$", shlex.join(run), flush=True)
        subprocess.run(run, check=True, cwd=ROOT)
        here = json.loads(out.with_suffix(".json").read_text())
        old = {row["family"]: row for row in committed["rows"]}
        new = {row["family"]: row for row in here["rows"]}
        differ = {
            family: sum(
                a != b
                for a, b in zip(
                    old[family]["task_success"], new[family]["task_success"], strict=True
                )
            )
            for family in ("blocked", "obstacles")
        }
        act = {f: (old[f]["median_act_ms"], new[f]["median_act_ms"]) for f in old}
        blocked = new["blocked"]
        tail = f"{blocked['act_p99_ms']:.1f} / {blocked['act_max_ms']:.1f}"
        if blocked.get("act_share_over_aim") is not None:  # (rows since session 41)
            tail += f" / {blocked['act_share_over_aim']:.3f}"
        lines.append(
            f"| {name} | {act['blocked'][0]:.2f} / {act['blocked'][1]:.2f} "
            f"| {act['obstacles'][0]:.2f} / {act['obstacles'][1]:.2f} "
            f"| {committed.get('machine', '?')} | {differ['blocked']}, {differ['obstacles']} "
            f"| {tail} |"
        )
        print(lines[-1], flush=True)
    (args.out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
