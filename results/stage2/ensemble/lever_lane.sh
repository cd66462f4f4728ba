#!/bin/bash
# One lane of session 33's pre-registered regressions for the 3-view students acting alone
# (README, "A wider encoder, and a longer regression (session 33)", and its session-34
# amendment): each a student regressed on the four 3-view DAgger runs' pooled data
# (runs/reseed/d3-seed1..4, rebuilt with rebuild_pool.sh), memory-mapped from one cache so that
# two lanes share it. A finished regression (policy.pt) is skipped; an unfinished one resumes
# from its last 1000 updates.
#   results/stage2/ensemble/lever_lane.sh NAME...
#   NAME: reg-sS (the shipped recipe's regression, seed S), wide32-s7, reg96k-s7, nodrop-s7,
#         pool8-sS (session 35: eight runs' data, runs/reseed/d3-seed1..8, 96000 steps; seed 7
#         first, seed 8 beside it in session 36), pool7-sS (the fallback if the eight runs'
#         cache is too slow: seeds 1..7), least4-sS (session 37: the four DAgger runs of
#         rebuild_pool.sh --least-offset, whose lookahead keeps the clean plan of least
#         deviation; 48000 steps), prev4-sS (session 50: the four DAgger runs of
#         rebuild_pool.sh --previous-action, whose students read the previous action; 48000
#         steps), tanh-prev4-sS (session 52: prev4's regression with the loss after the tanh,
#         distill README "The loss after the tanh"), l1-prev4-sS (the same with the absolute
#         error after the tanh), goal-prev4-sS (session 53: prev4's regression, the student
#         also reading the tip's offset to the goal, --goal-offset), center-prev4-sS (the
#         same regression on centre crops instead of random ones, --center-crops),
#         shift8-prev4-sS (random crops shifted up to 8 pixels instead of 4, --shift-padding 4),
#         cos-prev4-sS (session 54: the learning rate decayed to 0 along a cosine, --cosine),
#         wide32-prev4-sS (32 conv channels instead of 16, --encoder-channels 32),
#         wd0.1-prev4-sS, wd1-prev4-sS (decoupled weight decay 0.1 / 1, --set weight_decay=),
#         tip3-prev4-sS (states whose tip is within 5 cm of the target drawn 3 times as often),
#         ssm-prev4-sS (session 55: a spatial-softmax encoder, --spatial-softmax, on the
#         recipe's conv strides 2, 2, 1, 1), ssm21-prev4-sS (the same on strides 2, 1, 1, 1)
# One block, read whole before it runs: the script can be edited while a lane runs it.
{
set -e
cd "$(dirname "$0")/../../.."  # the repository root
export MUJOCO_GL=egl OMP_NUM_THREADS=1
POOL4="runs/reseed/d3-seed2 runs/reseed/d3-seed3 runs/reseed/d3-seed4"
for NAME in "$@"; do
  SRC=runs/reseed/d3-seed1; POOL=$POOL4; CACHE=runs/pool-cache/d3-pool4-48k; SETS=""
  case "$NAME" in
    reg-s*) SEED=${NAME#reg-s}; OUT=runs/offline/d3-pool4-48k-s$SEED; ARGS="--updates 48000" ;;
    wide32-s7) SEED=7; OUT=runs/offline/d3-wide32-s7; ARGS="--updates 48000 --encoder-channels 32" ;;
    reg96k-s7) SEED=7; OUT=runs/offline/d3-pool4-96k-s7; ARGS="--updates 96000" ;;
    nodrop-s7) SEED=7; OUT=runs/offline/d3-nodrop-s7; ARGS="--updates 48000 --view-dropout 0" ;;
    pool[78]-s[0-9]*) N=${NAME:4:1}; SEED=${NAME#pool?-s}; OUT=runs/offline/d3-pool$N-96k-s$SEED
      ARGS="--updates 96000"
      for S in $(seq 5 $N); do POOL="$POOL runs/reseed/d3-seed$S"; done
      CACHE=runs/pool-cache/d3-pool$N ;;
    least4-s[0-9]*) SEED=${NAME#least4-s}; OUT=runs/offline/d3-least4-48k-s$SEED
      ARGS="--updates 48000"; SRC=runs/reseed/d3-least-seed1
      POOL="runs/reseed/d3-least-seed2 runs/reseed/d3-least-seed3 runs/reseed/d3-least-seed4"
      CACHE=runs/pool-cache/d3-least4 ;;
    prev4-s[0-9]* | tanh-prev4-s[0-9]* | l1-prev4-s[0-9]* | goal-prev4-s[0-9]* | center-prev4-s[0-9]* | \
    shift8-prev4-s[0-9]* | cos-prev4-s[0-9]* | wide32-prev4-s[0-9]* | wd*-prev4-s[0-9]* | \
    tip3-prev4-s[0-9]* | ssm-prev4-s[0-9]* | ssm21-prev4-s[0-9]*)
      KIND=${NAME%prev4-s*}; SEED=${NAME##*-s}; OUT=runs/offline/d3-${KIND}prev4-48k-s$SEED
      ARGS="--updates 48000"; SRC=runs/reseed/d3-prev-seed1
      POOL="runs/reseed/d3-prev-seed2 runs/reseed/d3-prev-seed3 runs/reseed/d3-prev-seed4"
      CACHE=runs/pool-cache/d3-prev4
      TANH="action_loss_weight=1 pre_squash_loss_weight=0.05"
      case "$KIND" in
        tanh-) SETS=$TANH ;;
        l1-) SETS="$TANH action_loss_kind=absolute" ;;
        goal-) ARGS="$ARGS --goal-offset" ;;
        center-) ARGS="$ARGS --center-crops" ;;
        shift8-) ARGS="$ARGS --shift-padding 4" ;;
        cos-) ARGS="$ARGS --cosine" ;;
        wide32-) ARGS="$ARGS --encoder-channels 32" ;;
        wd0.1-) SETS="weight_decay=0.1" ;;
        wd1-) SETS="weight_decay=1" ;;
        tip3-) SETS="near_tip_weight=3" ;;
        ssm-) ARGS="$ARGS --spatial-softmax" ;;
        ssm21-) ARGS="$ARGS --spatial-softmax --encoder-strides 2 1 1 1" ;;
        "") ;;
        *) echo "lever_lane.sh: unknown regression '$NAME'" >&2; exit 2 ;;
      esac ;;
    *) echo "lever_lane.sh: unknown regression '$NAME' (reg-sS, wide32-s7, reg96k-s7, nodrop-s7, pool8-sS, pool7-sS, least4-sS, prev4-sS, tanh-prev4-sS, l1-prev4-sS, goal-prev4-sS, center-prev4-sS, shift8-prev4-sS, cos-prev4-sS, wide32-prev4-sS, wd0.1-prev4-sS, wd1-prev4-sS, tip3-prev4-sS, ssm-prev4-sS, ssm21-prev4-sS)" >&2; exit 2 ;;
  esac
  [ -f $OUT/policy.pt ] && continue
  .venv/bin/python results/stage2/distill/offline.py $SRC $OUT $ARGS --torch-threads 1 \
    --pool $POOL --set seed=$SEED $SETS --pool-cache $CACHE
done
exit
}
