#!/bin/bash
# 3-view DAgger runs of the shipped recipe's command (rebuild_pool.sh) with the lookahead's
# least-offset choice among clean plans (session 37; README, "A teacher that bends least"):
# runs/reseed/d3-least-seedS, not committed. A rerun resumes a run from its last iteration; a
# finished run (summary.json) is skipped.
#   results/stage2/ensemble/least_pool.sh SEED...    (1 2 3 4: the four runs behind the pool)
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
for S in "$@"; do
  RUN=runs/reseed/d3-least-seed$S
  [ -f $RUN/summary.json ] && continue
  .venv/bin/clamgen distill --preset residual-cpu --env.env-id CLAMGen/ReachMixed-v0 \
    --distill.teacher results/stage2/distill/teacher/policy.pt --distill.iterations 10 \
    --distill.episodes-per-iteration 300 --distill.updates-per-iteration 4000 \
    --distill.pose-weight 1.0 --distill.lookahead-candidates 16 \
    --distill.lookahead-fixed-offsets --distill.lookahead-least-offset \
    --env.num-views 3 --agent.encoder.num-views 3 \
    --distill.seed $S --loop.torch-threads 1 --run-dir $RUN
done
