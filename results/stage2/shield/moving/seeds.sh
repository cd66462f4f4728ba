#!/usr/bin/env bash
# The moving-target test rows over training seeds (results/stage2/shield/README.md, "Session
# 44"): each committed seed of the shipped recipes, alone and in its hybrid, with the target
# moving at SPEED. Usage: seeds.sh SPEED (files seeds/<row>-<views>-seed<S>-0p2.*); an
# evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=results/stage2/shield/moving/seeds
policies=results/stage2/ensemble/seeds
speed=$1
mkdir -p "$out"
for vs in 3views:7 3views:8 3views:9 2views:11 2views:12 1view:11 1view:12; do
    v=${vs%:*} seed=${vs#*:}
    n=${v%view*}
    for row in residual hybrid; do
        stem="$out/$row-$v-seed$seed-${speed/./p}"
        [ -f "$stem.json" ] && continue
        args=(--policy "$policies/d${n}_seed${seed}_policy.pt")
        [ "$row" = hybrid ] && args+=(--depth-hybrid)
        python -m clamgen eval --table 2 "${args[@]}" --target-speed "$speed" --out "$stem"
    done
done
