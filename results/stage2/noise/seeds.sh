#!/usr/bin/env bash
# More training seeds of the noisy-depth rows (results/stage2/noise/README.md, "Over training
# seeds"): the students of the shipped recipes' other seeds (their committed copies,
# results/stage2/ensemble/seeds/d<V>_seed<S>_policy.pt; seed 5: the shipped student), alone,
# in the hybrid or with the escapes, the map told the noise model, with noisy depth; or in the
# hybrid whose map reads the policy's own views instead of 128-pixel depth cameras
# (hybrid-told64: the third pilot's setting, fine_test.py). Usage: seeds.sh K KIND V SEED...
# (KIND: alone | hybrid-told | escapes-told | hybrid-told64; V: 3 | 2 | 1); files seeds/<kind><V>_seed<S>_k<K>.*; an
# evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=results/stage2/noise/seeds
k=$1 kind=$2 v=$3; shift 3
case $v in 3) views="3 RGBD views" shipped=residual-3views ;;
           2) views="2 RGBD views" shipped=residual-2views ;;
           1) views="1 RGBD view" shipped=residual-1view ;; esac
for seed in "$@"; do
    stem="$out/$kind${v}_seed${seed}_k${k/./p}"
    [ -f "$stem.json" ] && continue
    name="CLAMGen, $views, student of the shipped \`$shipped\` recipe (ours), seed $seed"
    policy="results/stage2/ensemble/seeds/d${v}_seed${seed}_policy.pt"
    [ "$seed" = 5 ] && policy=$shipped
    case $kind in
        alone) args=() name="$name, alone" ;;
        hybrid-told) args=(--depth-hybrid --depth-noise-model-m "$k")
            name="$name + the hybrid's depth shield and planner, told the noise model" ;;
        escapes-told) args=(--depth-escapes --depth-noise-model-m "$k")
            name="$name + the depth shield and random escapes, told the noise model" ;;
        hybrid-told64) args=(--depth-shield-m 0.01 --depth-planner --depth-track-m 0.02
                --depth-noise-model-m "$k")
            name="$name + the hybrid's depth shield (on its own views) and planner, told the noise model" ;;
    esac
    python -m clamgen eval --table 2 --policy "$policy" \
        "${args[@]}" --depth-noise-m "$k" --num-tasks 200 \
        --name "$name, depth noise sd $k*z^2 m" --out "$stem"
done
