#!/bin/bash
# One lane of seeds of the shipped 2- or 1-view student recipe (results/stage2/ensemble/README.md,
# "More seeds"): for each distill seed S, a fresh student regressed 48000 steps on the pooled
# data of five DAgger runs, then DAgger continued two iterations, both with seed S.
#   results/stage2/ensemble/seed_lane.sh VIEWS SEED...    (VIEWS: 2 or 1)
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
V=$1; shift
case "$V" in
  2) EXTRA="" ;;
  1) EXTRA="--num-views 1" ;;
  *) echo "seed_lane.sh: VIEWS must be 2 or 1, got '$V'" >&2; exit 2 ;;
esac
SRC=runs/reseed/d2-seed4
for S in "$@"; do
  OUT=runs/offline/d${V}-pool5-48k-s${S}
  if [ ! -f $OUT/policy.pt ]; then
    .venv/bin/python results/stage2/distill/offline.py $SRC $OUT --updates 48000 --torch-threads 1 $EXTRA \
      --pool runs/reseed/d3-seed1 runs/reseed/d3-seed2 runs/reseed/d3-seed3 runs/reseed/d3-seed4 --set seed=$S
  fi
  .venv/bin/python results/stage2/distill/continue_dagger.py $OUT ${OUT}-dagger --iterations 2 --updates 6000 --new-share 0.2 --seed $S --torch-threads 1
done
