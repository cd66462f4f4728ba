#!/bin/bash
# Paired end-to-end timing of the residual-cpu preset, 12k env steps: the code before the
# stage-2 rebuild (e63de27, from git archive on PYTHONPATH) and today's, side by side.
set -e
cd "$(dirname "$0")/../../.."
export MUJOCO_GL=egl
rm -rf /tmp/old /tmp/e2e-old /tmp/e2e-new && mkdir -p /tmp/old
git archive e63de27 src | tar -x -C /tmp/old
( PYTHONPATH=/tmp/old/src /usr/bin/time -f "%e" -o /tmp/e2e-old.time .venv/bin/python -m clamgen.cli train-residual --preset residual-cpu --loop.total-env-steps 12000 --run-dir /tmp/e2e-old > /tmp/e2e-old.log 2>&1 ) &
( /usr/bin/time -f "%e" -o /tmp/e2e-new.time .venv/bin/python -m clamgen.cli train-residual --preset residual-cpu --loop.total-env-steps 12000 --run-dir /tmp/e2e-new > /tmp/e2e-new.log 2>&1 ) &
wait
echo "before: $(cat /tmp/e2e-old.time) s, now: $(cat /tmp/e2e-new.time) s"
