#!/bin/bash
# Session 37's pilot (README, "A teacher that bends least"): privileged DAgger students of the
# fixed-library lookahead teacher, earliest arrival (priv-fixed-sS) against least deviation
# (priv-least-sS), seeds given, then each scored on validation block 360000. A finished run
# (summary.json) is not run again; a killed one starts over (3-8 min). RULES="least" runs the
# least-deviation runs only and scores nothing (session 51: pooled against session 50's
# priv-fixed50 runs, pooled_pilot.sh).
#   results/stage2/distill/least_offset_lane.sh SEED...
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
for S in "$@"; do
  for RULE in ${RULES:-fixed least}; do
    RUN=runs/distill/priv-$RULE-s$S
    [ -f $RUN/summary.json ] && continue
    rm -rf $RUN
    EXTRA=""; [ $RULE = least ] && EXTRA="--distill.lookahead-least-offset"
    .venv/bin/clamgen distill --preset residual-obstacles --agent.arm-keypoints \
      --env.env-id CLAMGen/ReachMixed-v0 --run-dir $RUN \
      --distill.teacher results/stage2/distill/teacher/policy.pt --distill.iterations 6 \
      --distill.episodes-per-iteration 300 --distill.updates-per-iteration 4000 \
      --distill.lookahead-candidates 16 --distill.lookahead-fixed-offsets \
      --distill.seed $S --loop.torch-threads 1 $EXTRA
  done
done
[ -n "$RULES" ] && exit 0
for S in "$@"; do
  .venv/bin/python results/stage2/tune/validate.py runs/distill/priv-fixed-s$S/policy.pt \
    runs/distill/priv-least-s$S/policy.pt --num-tasks 300 --offset 360000
done
