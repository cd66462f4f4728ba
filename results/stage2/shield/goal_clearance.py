"""How tight are the blocked test tasks' goals, and who solves the tight ones (session 49; a
description of committed rows, nothing chosen on it).

For each of the 200 blocked Table 2 test tasks: the largest clearance any IK solution at the
target keeps from the true obstacles (MuJoCo's geom distances, every arm geom against every
obstacle; `goal_clearance.json`, written once). Then the committed rows' per-task success
(`task_success`) of each way of acting over the shipped recipes' training seeds (the rows of
the aims table: their means over all 200 tasks are its blocked column), split by that
clearance: under 5 mm, 5 mm to 1 cm, 1 cm and more (the depth wrappers keep 1 cm;
`shield/README.md`, session 49, found their stalls on such goals on training tasks). Prints a
Markdown table (`goal_clearance.md`).

    python results/stage2/shield/goal_clearance.py
"""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np

from clamgen.envs import ReachEnv
from clamgen.experiments.config import TEST_SEEDS
from clamgen.robot import ur5
from clamgen.robot.kinematics import solve_tip_position

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
CACHE = HERE / "goal_clearance.json"
OUT = HERE / "goal_clearance.md"
NUM_TASKS = 200
STRATA = (
    (-np.inf, 0.005, "under 5 mm"),
    (0.005, 0.01, "5 mm to 1 cm"),
    (0.01, np.inf, "1 cm or more"),
)
SEED5 = {
    "alone": "results/stage2/ensemble/{v}v-dagger+2_test.json",
    "hybrid": "results/table2/hybrid_residual-{name}.json",
    "escapes": "results/table2/escapes_residual-{name}.json",
    "escapes_planner": "results/table2/escapes_planner_residual-{name}.json",
}
"""The shipped seed's (5) committed row of each way of acting (`{v}`: views, `{name}`: the
policy's suffix)."""
KINDS = {"alone": "student", "hybrid": "hybrid", "escapes": "escapes"}
KINDS_1V = {"escapes_planner": "escapes_planner"}
WORDS = {
    "alone": "alone",
    "hybrid": "hybrid",
    "escapes": "escapes",
    "escapes_planner": "planner + escapes where it finds none",
}


def seed_rows() -> dict[str, list[str]]:
    """Per (views, way of acting), the committed test rows over training seeds: the shipped
    seed's and those of `../ensemble/seeds/` that exist."""
    seeds_dir = ROOT / "results/stage2/ensemble/seeds"
    rows = {}
    for views, name in ((3, "3views"), (2, "2views"), (1, "1view")):
        kinds = KINDS | (KINDS_1V if views == 1 else {})
        for kind, stem in kinds.items():
            paths = [SEED5[kind].format(v=views, name=name)]
            others = sorted(seeds_dir.glob(f"{stem}{views}_seed*.json"))
            paths += [str(path.relative_to(ROOT)) for path in others]
            rows[f"{views} view{'s' * (views > 1)}, {WORDS[kind]} ({len(paths)} seeds)"] = paths
    return rows


BASELINES = {
    "RRT on the 3-view depth map (`depth-rrt-3views`)": ["results/table2/depth_rrt_3views.json"],
    "RRT with the true scene (`rrt`)": ["results/table2/rrt.json"],
}


def arm_clearance(scene) -> float:
    """The arm's true clearance (m, capped at 0.1) from the obstacles in its current pose
    (MuJoCo's geom distances, every arm geom against every obstacle)."""
    model, data = scene.model, scene.data
    obstacles = [g for g in scene.obstacle_geoms.ravel() if model.geom_conaffinity[g]]
    fromto = np.zeros(6)
    return min(
        mujoco.mj_geomDistance(model, data, int(a), int(o), 0.1, fromto)
        for a in scene.robot_geoms
        for o in obstacles
    )


def solution_clearances(env: ReachEnv, seed: int) -> np.ndarray:
    """`arm_clearance` of each IK solution at the target of `env`'s task `seed`."""
    env.reset(seed=int(seed))
    scene = env.unwrapped.scene
    values = []
    for q in solve_tip_position(scene.target_position, reference_joints=ur5.HOME_JOINTS):
        scene.data.qpos[:] = q
        mujoco.mj_kinematics(scene.model, scene.data)
        values.append(arm_clearance(scene))
    return np.asarray(values)


def best_clearance(env: ReachEnv, seed: int) -> float:
    """The best true clearance (m) of the IK solutions at the target of `env`'s task `seed`
    (-inf where it has none)."""
    values = solution_clearances(env, seed)
    return float(values.max()) if len(values) else float("-inf")


def goal_clearances() -> list[float]:
    """Per blocked test task, the best true clearance of the goal's IK solutions (m)."""
    if CACHE.exists():
        return json.loads(CACHE.read_text())["best_clearance_m"]
    env = ReachEnv(num_obstacles=2, task_family="blocked")
    best = [best_clearance(env, int(seed)) for seed in TEST_SEEDS.seeds(NUM_TASKS)]
    first = int(TEST_SEEDS.start)
    CACHE.write_text(json.dumps({"first_seed": first, "best_clearance_m": best}, indent=1))
    return best


def blocked_row(path: str | Path) -> dict:
    """The blocked-family row of a committed Table 2 file (relative to the repository or
    absolute), checked to be the 200 blocked test tasks."""
    rows = json.loads((ROOT / path).read_text())["rows"]
    (row,) = [r for r in rows if r["family"] == "blocked"]
    if row["first_seed"] != TEST_SEEDS.start or row["num_tasks"] != NUM_TASKS:
        raise ValueError(f"{path}: not the 200 blocked test tasks")
    return row


def blocked_success(path: str) -> np.ndarray:
    return np.asarray(blocked_row(path)["task_success"], bool)


def strata(best: np.ndarray) -> tuple[list[np.ndarray], str]:
    """Per stratum of `STRATA`, which tasks (by their best clearance `best`) lie in it, and the
    table's header cells naming each with its count of tasks."""
    masks = [(low <= best) & (best < high) for low, high, _ in STRATA]
    counts = zip(STRATA, masks, strict=True)
    return masks, " | ".join(f"{name} ({int(m.sum())} tasks)" for (_, _, name), m in counts)


def main() -> None:
    best = np.asarray(goal_clearances())
    masks, header = strata(best)
    lines = [
        "Blocked test tasks by the best true clearance of the goal's IK solutions "
        "(`goal_clearance.py`); success per stratum, means over the listed seeds.",
        "",
        f"| row | all 200 | {header} |",
        "|---|---|" + "---|" * len(STRATA),
    ]
    for name, paths in (seed_rows() | BASELINES).items():
        success = np.mean([blocked_success(p) for p in paths], axis=0)
        cells = [f"{success[m].mean():.3f}" for m in masks]
        lines.append(f"| {name} | {success.mean():.3f} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    OUT.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
