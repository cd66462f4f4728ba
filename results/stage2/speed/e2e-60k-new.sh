#!/bin/bash
# Today's 60k-step residual-cpu run, for the before/after wall time against
# e2e-60k-old.sh (the code before the stage-2 rebuild). Both ran with one other training run
# on the 2-core machine for their whole duration (one torch thread each).
set -e
cd "$(dirname "$0")/../../.."
export MUJOCO_GL=egl
rm -rf runs/speed/e2e-60k-new && mkdir -p runs/speed
/usr/bin/time -f "%e" -o runs/speed/e2e-60k-new.time .venv/bin/python -m clamgen.cli \
  train-residual --preset residual-cpu --loop.total-env-steps 60000 --run-dir runs/speed/e2e-60k-new \
  > runs/speed/e2e-60k-new.log 2>&1
echo "now: $(cat runs/speed/e2e-60k-new.time) s"
