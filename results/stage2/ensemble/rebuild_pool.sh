#!/bin/bash
# Rebuild 3-view DAgger runs behind the seed lanes' pool (runs/reseed/d3-seedS, not committed)
# from their committed command (../shield/reseed/d3-seedS/config.json; README, "Seeds of the
# shipped 3-view recipe"). A rerun resumes a run from its last iteration; a finished run
# (summary.json) is skipped.
#   results/stage2/ensemble/rebuild_pool.sh SEED...    (the runs behind the pool: 1 2 3 4; 5-8 for
#   session 35's eight-run pool)
#   results/stage2/ensemble/rebuild_pool.sh --least-offset SEED...    (session 37: the same
#   command with the lookahead's least-offset choice among clean plans, README "A teacher that
#   bends least, on images"; runs/reseed/d3-least-seedS)
#   results/stage2/ensemble/rebuild_pool.sh --previous-action SEED...    (session 50: the same
#   command with the previous step's executed action as the student's input,
#   ../distill/README.md "The previous action as an input"; runs/reseed/d3-prev-seedS)
#   results/stage2/ensemble/rebuild_pool.sh --two-views 4    (the 2-view run that the 2- and
#   1-view recipes' pool adds to the four 3-view runs, from its sweep's command,
#   results/sweeps/shipped-1view.toml; README "More seeds for the shielded rows";
#   runs/reseed/d2-seed4)
# One block, read whole before it runs: the script can be edited while a lane runs it.
{
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
# (a test runs the script with a stub for clamgen that prints the command, and a RUN_ROOT of its own)
CLAMGEN=${CLAMGEN:-.venv/bin/clamgen}; RUN_ROOT=${RUN_ROOT:-runs/reseed}
PREFIX=d3-seed; VIEWS=3; RUN_OPTIONS="--distill.iterations 10 --distill.lookahead-fixed-offsets"
if [ "$1" = --least-offset ]; then
  PREFIX=d3-least-seed; RUN_OPTIONS="$RUN_OPTIONS --distill.lookahead-least-offset"; shift
elif [ "$1" = --previous-action ]; then
  PREFIX=d3-prev-seed; RUN_OPTIONS="$RUN_OPTIONS --env.previous-action --agent.previous-action"
  shift
elif [ "$1" = --two-views ]; then
  PREFIX=d2-seed; VIEWS=2; RUN_OPTIONS="--distill.iterations 6 --distill.lookahead-margin-m 0.03"
  shift
fi
for S in "$@"; do
  RUN=$RUN_ROOT/$PREFIX$S
  [ -f $RUN/summary.json ] && continue
  $CLAMGEN distill --preset residual-cpu --env.env-id CLAMGen/ReachMixed-v0 \
    --distill.teacher results/stage2/distill/teacher/policy.pt $RUN_OPTIONS \
    --distill.episodes-per-iteration 300 --distill.updates-per-iteration 4000 \
    --distill.pose-weight 1.0 --distill.lookahead-candidates 16 \
    --env.num-views $VIEWS --agent.encoder.num-views $VIEWS \
    --distill.seed $S --loop.torch-threads 1 --run-dir $RUN
done
exit
}
