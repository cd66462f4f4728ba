#!/usr/bin/env bash
# Session 48: the told hybrids (the map told the noise model) meeting a target that moves at
# 0.2 m/s, with noisy depth at K = 0.01, on the Table 2 test tasks; the same rows on exact depth
# are results/stage2/shield/moving/hybrid-track-<views>-0p2.*. Nothing is chosen on them.
# Usage: moving.sh VIEWS... (3views 2views 1view); an evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../.."
CLAMGEN=${CLAMGEN:-.venv/bin/clamgen}
for v in "$@"; do
    stem=results/stage2/noise/moving/hybrid-told-$v-k0p01-0p2
    [ -f "$stem.json" ] && continue
    MUJOCO_GL=${MUJOCO_GL:-egl} "$CLAMGEN" eval --table 2 --policy "residual-$v" --depth-hybrid \
        --depth-noise-model-m 0.01 --depth-noise-m 0.01 --target-speed 0.2 --out "$stem"
done
