#!/bin/bash
# Session 51's check (README, "The previous action, pooled"): the pilot's three privileged
# DAgger runs of each kind (priv-fixed50-sS, priv-prev-sS, seeds 1-3; previous_action_lane.sh)
# pooled and regressed afresh, as the vision recipe regresses its four runs (offline.py, 48000
# updates), regression seed given, then scored on validation block 560000 (300 blocked + 300
# standard tasks; never test seeds). A finished regression (policy.pt) is skipped; a killed one
# resumes from its last 1000 updates. KINDS="fixed50" or "prev" regresses one kind only and
# scores nothing (two lanes finishing together would score twice); without KINDS the scoring
# runs for the seeds whose two regressions have both finished.
#   results/stage2/distill/previous_action_pooled.sh SEED...
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
for S in "$@"; do
  for KIND in ${KINDS:-fixed50 prev}; do
    OUT=runs/offline/priv-$KIND-pool3-s$S
    [ -f $OUT/policy.pt ] && continue
    .venv/bin/python results/stage2/distill/offline.py runs/distill/priv-$KIND-s1 $OUT \
      --pool runs/distill/priv-$KIND-s2 runs/distill/priv-$KIND-s3 --updates 48000 \
      --set seed=$S --torch-threads 1
  done
done
[ -n "$KINDS" ] && exit 0
for S in "$@"; do
  [ -f runs/offline/priv-fixed50-pool3-s$S/policy.pt ] && [ -f runs/offline/priv-prev-pool3-s$S/policy.pt ] || continue
  .venv/bin/python results/stage2/tune/validate.py runs/offline/priv-fixed50-pool3-s$S/policy.pt \
    runs/offline/priv-prev-pool3-s$S/policy.pt --num-tasks 300 --offset 560000
done
