#!/usr/bin/env bash
# The hybrids in real time over training seeds (results/stage2/shield/README.md, "The hybrids
# in real time over training seeds"): each committed seed of the shipped recipes in its hybrid
# (`--depth-hybrid`), the target moving at 0.2 m/s, acting in real time. Usage:
# realtime_seeds.sh VIEWS:SEED... (files realtime/seeds/hybrid-track-latency-<views>-seed<S>-0p2.*);
# an evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=results/stage2/shield/moving/realtime/seeds
mkdir -p "$out"
for vs in "$@"; do
    v=${vs%:*} seed=${vs#*:}
    n=${v%view*}
    stem="$out/hybrid-track-latency-$v-seed$seed-0p2"
    [ -f "$stem.json" ] && continue
    python -m clamgen eval --table 2 --policy "results/stage2/ensemble/seeds/d${n}_seed${seed}_policy.pt" \
        --depth-hybrid --target-speed 0.2 --real-time --out "$stem"
done
