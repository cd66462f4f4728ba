#!/bin/bash
# One lane of seeds of a shipped student recipe (results/stage2/ensemble/README.md, "More
# seeds"): for each distill seed S, a fresh student regressed 48000 steps on the pooled data of
# the DAgger runs (3 views: four 3-view runs; 2 and 1 views: those and a 2-view run), then
# DAgger continued two iterations, both with seed S. The pool is memory-mapped from
# runs/pool-cache/ so that two lanes of the same view count share it in memory.
# Run again after a kill, a lane goes on where it stopped: a finished regression (policy.pt)
# is skipped, an unfinished one resumes from its last 1000 updates, a continuation from its
# last iteration.
#   results/stage2/ensemble/seed_lane.sh VIEWS SEED...    (VIEWS: 3, 2 or 1)
# One block, read whole before it runs: the script can be edited while a lane runs it.
{
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
V=$1; shift
case "$V" in
  3) SRC=runs/reseed/d3-seed1; POOL="runs/reseed/d3-seed2 runs/reseed/d3-seed3 runs/reseed/d3-seed4"
     EXTRA=""; NAME=d3-pool4-48k ;;
  2) SRC=runs/reseed/d2-seed4; POOL="runs/reseed/d3-seed1 runs/reseed/d3-seed2 runs/reseed/d3-seed3 runs/reseed/d3-seed4"
     EXTRA=""; NAME=d2-pool5-48k ;;
  1) SRC=runs/reseed/d2-seed4; POOL="runs/reseed/d3-seed1 runs/reseed/d3-seed2 runs/reseed/d3-seed3 runs/reseed/d3-seed4"
     EXTRA="--num-views 1"; NAME=d1-pool5-48k ;;
  *) echo "seed_lane.sh: VIEWS must be 3, 2 or 1, got '$V'" >&2; exit 2 ;;
esac
CACHE=runs/pool-cache/$NAME
for S in "$@"; do
  OUT=runs/offline/${NAME}-s${S}
  if [ ! -f $OUT/policy.pt ]; then
    .venv/bin/python results/stage2/distill/offline.py $SRC $OUT --updates 48000 --torch-threads 1 $EXTRA \
      --pool $POOL --set seed=$S --pool-cache $CACHE
  fi
  .venv/bin/python results/stage2/distill/continue_dagger.py $OUT ${OUT}-dagger --iterations 2 --updates 6000 --new-share 0.2 --seed $S --torch-threads 1 --pool-cache $CACHE
done
exit
}
