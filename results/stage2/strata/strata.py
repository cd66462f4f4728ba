"""Success, collisions and time to arrive on the blocked test tasks, split by how tight the goal
is (session 50; a description of committed policies on the committed test tasks, nothing
chosen on it).

`rerun.sh` re-evaluated every way of acting of the aims table on the 200 blocked test tasks
for each training seed whose checkpoint is committed, so that each row records per task
whether it collided and how many control steps it took (rows measured before session 49
record success only). This script

- checks each re-run against the committed row it repeats (tasks whose success differs);
- splits the blocked tasks by the best true clearance any IK solution at the target keeps from
  the obstacles (`../shield/goal_clearance.json`, read by `goal_clearance.py`, whose committed
  rows and words this script shares): under 1 cm ("tight", the margin the depth
  wrappers keep) and 1 cm or more;
- reports per stratum success and collision rate, means over seeds, with a 95% bootstrap
  interval over tasks (`scipy.stats.bootstrap`, percentile, on the per-task means over seeds:
  the seeds are those measured, the tasks a sample of the family);
- reports time to arrive: the median control steps (50 ms each) of the successful episodes.

    python results/stage2/strata/strata.py     # writes strata.md
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.stats

from clamgen.envs import CONTROL_DT_S

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(HERE.parent / "shield"))  # the tight-goal description's helpers
from goal_clearance import (  # noqa: E402
    KINDS,
    KINDS_1V,
    SEED5,
    WORDS,
    blocked_row,
    goal_clearances,
)

OUT = HERE / "strata.md"
TIGHT_M = 0.01
"""Goals whose every IK solution comes within this of an obstacle are "tight" (the margin the
depth shield and its planner keep)."""
SEEDS = {3: (5, 7, 8, 9), 2: (5, 11, 12), 1: (5, 11, 12)}
"""Training seeds re-run per view count: those whose checkpoints are committed (the aims table
also has seeds 7 and 8 of two views and 7, 8, 9 of one view, whose checkpoints are not)."""
NAMES = {3: "3views", 2: "2views", 1: "1view"}
BASELINES = {
    "rrt": ("RRT with the true scene", "results/table2/rrt.json"),
    "depth-rrt-3views": ("RRT on the 3-view depth map", "results/table2/depth_rrt_3views.json"),
    "ik": ("IK interpolation", "results/table2/ik.json"),
}
BOOT_RESAMPLES = 10_000
BOOT_SEED = 0


def committed(way: str, views: int, seed: int) -> Path:
    """The committed row a re-run repeats: the shipped seed's (`goal_clearance.SEED5`) or
    another seed's in `results/stage2/ensemble/seeds/`."""
    if seed == 5:
        return ROOT / SEED5[way].format(v=views, name=NAMES[views])
    stem = (KINDS | KINDS_1V)[way]
    return ROOT / f"results/stage2/ensemble/seeds/{stem}{views}_seed{seed}.json"


def groups() -> dict[str, list[tuple[Path, Path]]]:
    """Per row of the output, its (re-run, committed) files, one pair per seed."""
    out = {}
    for views, seeds in SEEDS.items():
        ways = ("alone", "hybrid", "escapes") + (("escapes_planner",) if views == 1 else ())
        for way in ways:
            word = "view" if views == 1 else "views"
            name = f"{views} {word}, {WORDS[way]} (seeds {', '.join(map(str, seeds))})"
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
    best = np.asarray(goal_clearances())
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
