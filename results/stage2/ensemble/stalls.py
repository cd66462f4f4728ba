"""What the 3-view students' stalls on the yardstick block look like (session 52; a description,
nothing chosen on it).

`block_strata.py` found most failures of the shipped recipe's regressions on block 350000's
blocked tasks with a roomy goal (best IK clearance 1 cm or more) to be stalls: 100 steps, no
collision, the tip never within the 2 cm of success. Each such task is run again with the
student (`ensemble.py`'s names; deterministic, so the same episode), recording the tip's
distance to the target at every step, and at the end the arm's clearance from the obstacles
(MuJoCo's geom distances). Prints one line per stall and a summary per student: where the tip
ended (within 5 cm of the target, 5-15 cm, farther), how far it came in its best step, how
much it moved in the last 50 steps, and whether the arm ended within 1 cm of an obstacle.

    python results/stage2/ensemble/stalls.py --students 3v-reg-s7 3v-reg-s8 3v-reg-s9
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from block_strata import CACHE, blocked_lines  # (this directory: the script's own)
from ensemble import load
from goal_clearance import arm_clearance  # (../shield/, put on the path by block_strata)

from clamgen.envs import ReachEnv
from clamgen.experiments.evaluate import run_episode

ROOMY_M = 0.01  # goals whose best IK solution keeps this clearance (block_strata's last stratum)
TAIL_STEPS = 50  # how much the tip moved over an episode's last steps
NEAR_M = 0.01  # an arm this close to an obstacle at the end is pressed against it


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--students", nargs="+", default=["3v-reg-s7", "3v-reg-s8", "3v-reg-s9"])
    args = parser.parse_args()
    lines = blocked_lines()
    best = json.loads(CACHE.read_text())
    for name in args.students:
        line = lines[name]
        if best["seeds"] != line["seeds"]:
            raise ValueError(f"{CACHE}: other tasks than {name}'s line")
        stalls = [
            seed
            for seed, ok, hit, roomy in zip(
                line["seeds"],
                line["success"],
                line["collided"],
                best["best_clearance_m"],
                strict=True,
            )
            if not ok and not hit and roomy >= ROOMY_M
        ]
        policy, kwargs = load(name)
        env = ReachEnv(num_obstacles=2, task_family="blocked", **kwargs)
        rows = []
        for seed in stalls:
            distances = []

            def watch(obs, info, done, distances=distances):
                distances.append(float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])))

            record = run_episode(env, policy, seed, on_step=watch)
            if record.reached or record.collided or record.steps < TAIL_STEPS:
                # The line was written on a CPU whose convs round otherwise (its `machine`).
                print(f"{name} {seed}: not a stall here (reached or collided), skipped")
                continue
            d = np.asarray(distances)
            moved = abs(d[-1] - d[-TAIL_STEPS])
            rows.append((seed, d[0], d.min(), d[-1], moved, arm_clearance(env.unwrapped.scene)))
            print(
                f"{name} {seed}: start {d[0]:.3f} m, closest {d.min():.3f}, end {d[-1]:.3f}, "
                f"last {TAIL_STEPS} steps moved {moved:.3f}, arm clearance {rows[-1][5]:.3f}"
            )
        env.close()
        ends = np.asarray([r[3] for r in rows])
        buckets = (ends < 0.05).sum(), ((ends >= 0.05) & (ends < 0.15)).sum(), (ends >= 0.15).sum()
        print(
            f"{name}: {len(rows)} stalls on roomy goals of {len(stalls)} recorded; ended within "
            f"5 cm / 5-15 cm / farther: {' / '.join(str(int(b)) for b in buckets)}; closest "
            f"approach median {np.median([r[2] for r in rows]):.3f} m; moved under 1 cm in the "
            f"last {TAIL_STEPS} steps {sum(r[4] < 0.01 for r in rows)}; arm within "
            f"{NEAR_M * 100:.0f} cm of an obstacle at the end {sum(r[5] < NEAR_M for r in rows)}"
        )


if __name__ == "__main__":
    main()
