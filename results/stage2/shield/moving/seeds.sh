#!/usr/bin/env bash
# The moving-target test rows over training seeds (results/stage2/shield/README.md, "Session
# 44"): each committed seed of the shipped recipes, alone and in its hybrid, with the target
# moving at SPEED. Usage: seeds.sh SPEED [ROWS...] (files seeds/<row>-<views>-seed<S>-0p2.*;
# rows residual and hybrid by default, hybrid-track on request); an evaluation whose JSON
# exists is skipped. The hybrid row is the hybrid as committed until session 44 (its planner
# planning to where the target is, `--depth-track-m 0`); hybrid-track is `--depth-hybrid`
# since (the planner meeting the target).
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=results/stage2/shield/moving/seeds
policies=results/stage2/ensemble/seeds
speed=$1; shift
rows=("$@")
[ $# -eq 0 ] && rows=(residual hybrid)
mkdir -p "$out"
for vs in 3views:7 3views:8 3views:9 2views:11 2views:12 1view:11 1view:12; do
    v=${vs%:*} seed=${vs#*:}
    n=${v%view*}
    for row in "${rows[@]}"; do
        stem="$out/$row-$v-seed$seed-${speed/./p}"
        [ -f "$stem.json" ] && continue
        args=(--policy "$policies/d${n}_seed${seed}_policy.pt")
        if [ "$row" = hybrid ]; then
            args+=(--depth-shield-m 0.01 --depth-planner --depth-fine-size 128 --depth-track-m 0)
            [ "$v" = 1view ] && args+=(--depth-shadow-m 0.05 --depth-shadow-behind-surfaces)
        fi
        [ "$row" = hybrid-track ] && args+=(--depth-hybrid)
        python -m clamgen eval --table 2 "${args[@]}" --target-speed "$speed" --out "$stem"
    done
done
