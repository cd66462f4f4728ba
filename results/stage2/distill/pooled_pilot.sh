#!/bin/bash
# A privileged pilot read the way the vision recipe regresses (README, "The previous action,
# pooled", session 51): the three privileged DAgger runs of one kind (runs/distill/priv-KIND-s1..3,
# from previous_action_lane.sh or least_offset_lane.sh) pooled and regressed afresh (offline.py,
# 48000 updates), one regression per seed given, into runs/offline/priv-KIND-pool3-sSEED. A
# finished regression (policy.pt) is skipped; a killed one resumes from its last 1000 updates.
# Scoring is validate.py's, on the block the README names.
#   results/stage2/distill/pooled_pilot.sh KIND SEED...
# A regression setting as the lever (session 52): TAG names it and SETS holds its distill
# settings, the output then runs/offline/priv-KIND-TAG-pool3-sSEED, e.g.
#   TAG=tanh SETS="action_loss_weight=1 pre_squash_loss_weight=0.05" \
#       results/stage2/distill/pooled_pilot.sh fixed50 7
# ARGS holds other offline.py options of the lever (session 53), e.g.
#   TAG=goal ARGS=--goal-offset results/stage2/distill/pooled_pilot.sh fixed50 7 8
# One block, read whole before it runs: the script can be edited while a lane runs it.
{
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
KIND=$1; shift
NAME=priv-$KIND${TAG:+-$TAG}
for S in "$@"; do
  OUT=runs/offline/$NAME-pool3-s$S
  [ -f $OUT/policy.pt ] && continue
  .venv/bin/python results/stage2/distill/offline.py runs/distill/priv-$KIND-s1 $OUT \
    --pool runs/distill/priv-$KIND-s2 runs/distill/priv-$KIND-s3 --updates 48000 \
    --set seed=$S $SETS $ARGS --torch-threads 1
done
exit
}
