#!/usr/bin/env bash
# Session 48: the told hybrids (the map told the noise model) meeting a target that moves at
# 0.2 m/s, with noisy depth at K = 0.01, on the Table 2 test tasks; the same rows on exact depth
# are results/stage2/shield/moving/hybrid-track-<views>-0p2.*. Nothing is chosen on them.
# Usage: moving.sh VIEWS [SEED...] (VIEWS: 3views 2views 1view): without seeds the shipped
# student (files moving/hybrid-told-<views>-k0p01-0p2.*); with seeds the other students of its
# recipe (results/stage2/ensemble/seeds/d<V>_seed<S>_policy.pt; files ...-0p2-seed<S>.*).
# An evaluation whose JSON exists is skipped; `python results/stage2/noise/moving.py` sums
# them up over seeds.
set -euo pipefail
cd "$(dirname "$0")/../../.."
CLAMGEN=${CLAMGEN:-.venv/bin/clamgen}
v=$1; shift
stems=("results/stage2/noise/moving/hybrid-told-$v-k0p01-0p2")
policies=("residual-$v")
for seed in "$@"; do
    stems+=("results/stage2/noise/moving/hybrid-told-$v-k0p01-0p2-seed$seed")
    policies+=("results/stage2/ensemble/seeds/d${v:0:1}_seed${seed}_policy.pt")
done
for i in "${!stems[@]}"; do
    [ -f "${stems[$i]}.json" ] && continue
    MUJOCO_GL=${MUJOCO_GL:-egl} "$CLAMGEN" eval --table 2 --policy "${policies[$i]}" \
        --depth-hybrid --depth-noise-model-m 0.01 --depth-noise-m 0.01 --target-speed 0.2 \
        --out "${stems[$i]}"
done
