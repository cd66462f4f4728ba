#!/bin/bash
# One lane of student seeds (results/stage2/ensemble/README.md, "More seeds"; usage: seed_lane.sh VIEWS SEED...): regression (48000 steps, distill seed S) then two DAgger continuation iterations (distill seed S).
set -e
cd /work/main
export MUJOCO_GL=egl OMP_NUM_THREADS=1
V=$1; shift
for S in "$@"; do
  if [ "$V" = 2 ]; then SRC=runs/reseed/d2-seed4; EXTRA=""; else SRC=runs/reseed/d2-seed4; EXTRA="--num-views 1"; fi
  OUT=runs/offline/d${V}-pool5-48k-s${S}
  if [ ! -f $OUT/policy.pt ]; then
    .venv/bin/python results/stage2/distill/offline.py $SRC $OUT --updates 48000 --torch-threads 1 $EXTRA \
      --pool runs/reseed/d3-seed1 runs/reseed/d3-seed2 runs/reseed/d3-seed3 runs/reseed/d3-seed4 --set seed=$S
  fi
  .venv/bin/python results/stage2/distill/continue_dagger.py $OUT ${OUT}-dagger --iterations 2 --updates 6000 --new-share 0.2 --seed $S --torch-threads 1
done
