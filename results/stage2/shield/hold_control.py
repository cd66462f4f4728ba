"""No policy at all inside the depth wrappers: the arm holds still, so the wrapper alone acts
(session 42's second control; README.md, "Session 42").

    python results/stage2/shield/hold_control.py [--views 3 2 1] [--wrapper hybrid]

`HoldStill` (`clamgen.policy`) commands zero joint motion every step. Inside a hybrid
(`depth_planner.HYBRID`), the planner sees the arm stalled after its window (`STUCK_STEPS`)
and plans on the depth map the views have shown, follows the path through the shield, and
plans again when stuck (up to `MAX_PLANS`); inside `ESCAPES_PLANNER` the random escapes go on
where it finds no path. The env renders each number of views at the shipped residuals' 64
pixels (and the presets' 128-pixel depth cameras), as `clamgen eval --depth-views` does.
Writes the Table 2 row of both families on the test tasks to
`results/table2/hold_through_<wrapper>_<views>.json` / `.md`.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

import torch

from clamgen.cli import EvalConfig, depth_views_env, guarded_row_name
from clamgen.experiments.depth_planner import ESCAPES_PLANNER, HYBRID
from clamgen.experiments.machine import describe
from clamgen.experiments.policies import views_suffix
from clamgen.experiments.tables import table2_row, write_table2
from clamgen.policy import HoldStill

TABLE2 = Path(__file__).resolve().parents[2] / "table2"
WRAPPERS = {"hybrid": HYBRID, "escapes-planner": ESCAPES_PLANNER}
FIRST_SEED = EvalConfig.first_seed  # the test tasks of every Table 2 row
NUM_TASKS = EvalConfig.num_tasks


def run(views: int, wrapper: str) -> Path:
    guard = WRAPPERS[wrapper][views]
    policy, env_kwargs = guard.around(HoldStill(), depth_views_env({}, views))
    name = guarded_row_name("no policy (the arm holds still)", guard.describe(), views)
    rows = [
        table2_row(name, policy, NUM_TASKS, env_kwargs, family, FIRST_SEED)
        for family in ("obstacles", "blocked")
    ]
    for row in rows:
        print(f"{views} view(s), {wrapper}, {row.family}: success {row.success_rate:.3f}, "
              f"collisions {row.collision_rate:.3f}", flush=True)  # fmt: skip
    suffix = views_suffix(views)
    out = TABLE2 / f"hold_through_{wrapper.replace('-', '_')}_{suffix}"
    meta = {
        "policy": "hold (zero command)" + guard.describe(),
        "num_tasks": NUM_TASKS,
        "first_seed": FIRST_SEED,
        "command": "python results/stage2/shield/hold_control.py "
        + shlex.join(["--views", str(views), "--wrapper", wrapper]),
        "machine": describe(),
    }
    write_table2(rows, out, meta)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, nargs="+", default=[3, 2, 1], choices=(3, 2, 1))
    parser.add_argument("--wrapper", choices=tuple(WRAPPERS), default="hybrid")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for views in args.views:
        print("wrote", run(views, args.wrapper).with_suffix(".json"), file=sys.stderr)


if __name__ == "__main__":
    main()
