"""Success, collisions and time to arrive on the blocked test tasks, split by how tight the goal
is (session 50; a description of committed policies on the committed test tasks, nothing
chosen on it).

`rerun.sh` re-evaluated every way of acting of the aims table on the 200 blocked test tasks
for each training seed whose checkpoint is committed, so that each row records per task
whether it collided and how many control steps it took (rows measured before session 49
record success only). This script

- checks each re-run against the committed row it repeats (tasks whose success differs);
- splits the blocked tasks by the best true clearance any IK solution at the target keeps from
  the obstacles (`../shield/goal_clearance.json`): under 1 cm ("tight", the margin the depth
  wrappers keep) and 1 cm or more;
- reports per stratum success and collision rate, means over seeds, with a 95% bootstrap
  interval over tasks (`scipy.stats.bootstrap`, percentile, on the per-task means over seeds:
  the seeds are those measured, the tasks a sample of the family);
- reports time to arrive: the median control steps (50 ms each) of the successful episodes.

    python results/stage2/strata/strata.py     # writes strata.md
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import scipy.stats

from clamgen.envs import CONTROL_DT_S
from clamgen.experiments.config import TEST_SEEDS

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
OUT = HERE / "strata.md"
TIGHT_M = 0.01
"""Goals whose every IK solution comes within this of an obstacle are "tight" (the margin the
depth shield and its planner keep)."""
CLEARANCES = HERE.parent / "shield" / "goal_clearance.json"
SEEDS = {3: (5, 7, 8, 9), 2: (5, 11, 12), 1: (5, 11, 12)}
"""Training seeds re-run per view count: those whose checkpoints are committed (the aims table
also has seeds 7 and 8 of two views and 7, 8, 9 of one view, whose checkpoints are not)."""
NAMES = {3: "3views", 2: "2views", 1: "1view"}
WAYS = {
    "alone": ("alone", "results/stage2/ensemble/{v}v-dagger+2_test.json", "student"),
    "hybrid": ("hybrid", "results/table2/hybrid_residual-{name}.json", "hybrid"),
    "escapes": ("escapes", "results/table2/escapes_residual-{name}.json", "escapes"),
    "escapes_planner": (
        "planner + escapes where it finds none",
        "results/table2/escapes_planner_residual-{name}.json",
        "escapes_planner",
    ),
}
"""Per way of acting: its words, the shipped seed's committed row, the stem of the other seeds'
committed rows in `results/stage2/ensemble/seeds/`."""
BASELINES = {
    "rrt": ("RRT with the true scene", "results/table2/rrt.json"),
    "depth-rrt-3views": ("RRT on the 3-view depth map", "results/table2/depth_rrt_3views.json"),
    "ik": ("IK interpolation", "results/table2/ik.json"),
}
BOOT_RESAMPLES = 10_000
BOOT_SEED = 0


def blocked_row(path: Path) -> dict:
    rows = json.loads(path.read_text())["rows"]
    (row,) = [r for r in rows if r["family"] == "blocked"]
    if row["first_seed"] != TEST_SEEDS.start or row["num_tasks"] != 200:
        raise ValueError(f"{path}: not the 200 blocked test tasks")
    return row


def committed(way: str, views: int, seed: int) -> Path:
    if seed == 5:
        return ROOT / WAYS[way][1].format(v=views, name=NAMES[views])
    return ROOT / f"results/stage2/ensemble/seeds/{WAYS[way][2]}{views}_seed{seed}.json"


def groups() -> dict[str, list[tuple[Path, Path]]]:
    """Per row of the output, its (re-run, committed) files, one pair per seed."""
    out = {}
    for views, seeds in SEEDS.items():
        ways = ("alone", "hybrid", "escapes") + (("escapes_planner",) if views == 1 else ())
        for way in ways:
            word = "view" if views == 1 else "views"
            name = f"{views} {word}, {WAYS[way][0]} (seeds {', '.join(map(str, seeds))})"
            out[name] = [
                (HERE / f"{way}{views}_seed{s}.json", committed(way, views, s)) for s in seeds
            ]
    for stem, (words, path) in BASELINES.items():
        out[words] = [(HERE / f"{stem}.json", ROOT / path)]
    return out


def interval(per_task: np.ndarray) -> str:
    """The mean of per-task values with its 95% bootstrap interval over tasks."""
    mean = float(per_task.mean())
    if np.ptp(per_task) == 0:
        return f"{mean:.3f}"
    res = scipy.stats.bootstrap(
        (per_task,),
        np.mean,
        n_resamples=BOOT_RESAMPLES,
        method="percentile",
        random_state=np.random.default_rng(BOOT_SEED),
    )
    low, high = res.confidence_interval
    return f"{mean:.3f} ({low:.3f}-{high:.3f})"


def main() -> None:
    best = np.asarray(json.loads(CLEARANCES.read_text())["best_clearance_m"])
    tight = best < TIGHT_M
    strata = ((tight, f"tight ({int(tight.sum())})"), (~tight, f"other ({int((~tight).sum())})"))
    lines = [
        "Blocked test tasks split by the best true clearance of the goal's IK solutions "
        f"(tight: under {TIGHT_M * 100:.0f} cm; `strata.py`). Means over the listed seeds with 95% "
        "bootstrap intervals over tasks; time to arrive: median control steps of the successful "
        f"episodes ({CONTROL_DT_S * 1000:.0f} ms each). The last column counts, summed over seeds, "
        "tasks whose success differs from the committed row the re-run repeats.",
        "",
        "| row | success, all 200 | success, "
        + " | success, ".join(w for _, w in strata)
        + " | collisions, all 200 | collisions, "
        + " | collisions, ".join(w for _, w in strata)
        + " | steps to arrive, tight / other | differs from committed |",
        "|---|" + "---|" * 9,
    ]
    for name, pairs in groups().items():
        missing = [str(p.relative_to(ROOT)) for p, _ in pairs if not p.exists()]
        if missing:
            print(f"{name}: not yet measured ({', '.join(missing)})")
            continue
        rows = [blocked_row(p) for p, _ in pairs]
        success = np.array([r["task_success"] for r in rows], float)
        collided = np.array([r["task_collided"] for r in rows], float)
        steps = np.array([r["task_steps"] for r in rows], float)
        differs = sum(
            int(np.sum(np.asarray(blocked_row(c)["task_success"]) != s.astype(bool)))
            for (_, c), s in zip(pairs, success, strict=True)
        )
        cells = [interval(success.mean(0))]
        cells += [interval(success.mean(0)[m]) for m, _ in strata]
        cells += [interval(collided.mean(0))]
        cells += [interval(collided.mean(0)[m]) for m, _ in strata]
        arrive = [steps[:, m][success[:, m] > 0] for m, _ in strata]
        cells += [" / ".join(f"{np.median(a):.0f}" if a.size else "-" for a in arrive)]
        cells += [str(differs)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    OUT.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
