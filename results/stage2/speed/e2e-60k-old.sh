#!/bin/bash
# The 60k-step residual-cpu run of the code before the stage-2 rebuild (e63de27, from git
# archive on PYTHONPATH; its own residual-cpu preset, the paper-faithful fp32 update), for the
# before/after wall time against today's 60k run (`speed-bf16-online`, 2849 s). Like that run,
# it shared the 2-core machine with one other training run for its whole duration.
set -e
cd "$(dirname "$0")/../../.."
export MUJOCO_GL=egl
rm -rf /tmp/old runs/speed/e2e-60k-old && mkdir -p /tmp/old runs/speed
git archive e63de27 src | tar -x -C /tmp/old
PYTHONPATH=/tmp/old/src /usr/bin/time -f "%e" -o runs/speed/e2e-60k-old.time .venv/bin/python -m clamgen.cli \
  train-residual --preset residual-cpu --loop.total-env-steps 60000 --run-dir runs/speed/e2e-60k-old \
  > runs/speed/e2e-60k-old.log 2>&1
echo "before: $(cat runs/speed/e2e-60k-old.time) s"
