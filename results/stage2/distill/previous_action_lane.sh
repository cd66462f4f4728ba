#!/bin/bash
# Session 50's pilot (README, "The previous action as an input"): privileged DAgger students of
# the fixed-library lookahead teacher (session 37's priv-fixed recipe), without (priv-fixed50-sS)
# and with the previous step's executed action as an input (priv-prev-sS: --env.previous-action
# --agent.previous-action), seeds given, then each scored on validation block 550000 (300
# blocked + 300 standard tasks; never test seeds). A finished run (summary.json) is not run
# again; a killed one resumes after its last finished iteration. KINDS="fixed50" or "prev" runs
# one kind only (two lanes of three runs each); the scoring runs for the seeds whose two runs
# have both finished.
#   results/stage2/distill/previous_action_lane.sh SEED...
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
for S in "$@"; do
  for KIND in ${KINDS:-fixed50 prev}; do
    RUN=runs/distill/priv-$KIND-s$S
    [ -f $RUN/summary.json ] && continue
    EXTRA=""; [ $KIND = prev ] && EXTRA="--env.previous-action --agent.previous-action"
    .venv/bin/clamgen distill --preset residual-obstacles --agent.arm-keypoints \
      --env.env-id CLAMGen/ReachMixed-v0 --run-dir $RUN \
      --distill.teacher results/stage2/distill/teacher/policy.pt --distill.iterations 6 \
      --distill.episodes-per-iteration 300 --distill.updates-per-iteration 4000 \
      --distill.lookahead-candidates 16 --distill.lookahead-fixed-offsets \
      --distill.seed $S --loop.torch-threads 1 $EXTRA
  done
done
for S in "$@"; do
  [ -f runs/distill/priv-fixed50-s$S/summary.json ] && [ -f runs/distill/priv-prev-s$S/summary.json ] || continue
  .venv/bin/python results/stage2/tune/validate.py runs/distill/priv-fixed50-s$S/policy.pt \
    runs/distill/priv-prev-s$S/policy.pt --num-tasks 300 --offset 550000
done
