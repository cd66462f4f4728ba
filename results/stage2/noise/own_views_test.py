"""Validation pilot (session 48): with noisy depth and the ray target test, the told hybrids'
map on the policy's own 64-pixel views instead of their 128-pixel depth cameras, from 3, 2 and
1 view(s).

Session 46's pilot 3 (`fine_test.py`, block 500000, the sphere target test, 3 and 2 views)
met its rule for the policy's own views (3 successes fewer and 4 collisions more of 400, every
act median lower), and the hybrid's preset was left on its 128-pixel cameras. Session 47 put
the told map's target test along each ray; over seeds on the test tasks the hybrids on their
own views then met every success and collision aim and acted in 1.64-2.20 ms, the preset's in
2.3-3.2 ms (the act-time aim: under 2 ms). Test rows choose nothing, so the question is asked
again here, on validation tasks, with the committed map, and with 1 view too (whose hybrid
also reads a 128-pixel camera).

Protocol (written before any run): the shipped 3-, 2- and 1-view residuals in their hybrids
told the noise (`HYBRID[v]` with `noise_m=K`), the map on 128-pixel cameras (`--test
cameras-128`, the committed preset) against the policy's own views (`--test own-64`:
`fine_depth_size=0`, nothing else changed), K = 0.003 and 0.01, on 100 blocked and 50
standard validation tasks from offset 530000 (a block no earlier check used), the same tasks
for both, run side by side on the two cores. Rule: `--depth-hybrid` told the noise
(`--depth-noise-model-m K`) puts its map on the policy's own views if, summed over the six
blocked rows, `own-64` loses at most 6 successes of 600 and collides at most 6 more times,
loses at most 3 standard successes of 300, and its blocked act median is lower in every row.
Otherwise the preset stays as committed and this file says so.

    python results/stage2/noise/own_views_test.py --test cameras-128
    python results/stage2/noise/own_views_test.py --test own-64
    python results/stage2/noise/own_views_test.py --summary

One JSON line per (test, views, K, family) in own_views_test.jsonl (per task: success,
collision, steps; the blocked act median; the installed code's commit).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from fine_test import pilot_line, pilot_main

from clamgen.experiments.depth_planner import HYBRID

HERE = Path(__file__).resolve().parent
OUT = HERE / "own_views_test.jsonl"
OFFSET = 530_000
TESTS = {"cameras-128": 128, "own-64": 0}
"""The map's depth: 128-pixel cameras (the committed preset) or the policy's own views (0)."""


def run(test: str, views: int, noise_m: float, family: str) -> dict:
    guard = replace(HYBRID[views], fine_depth_size=TESTS[test], noise_m=noise_m)
    return pilot_line(test, views, noise_m, family, guard, OFFSET)


if __name__ == "__main__":
    pilot_main(__doc__, TESTS, (3, 2, 1), run, OUT)
