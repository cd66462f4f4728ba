#!/usr/bin/env bash
# The shipped residuals alone with noisy depth (the residual rows of run.sh without its
# wrapper rows). Usage: residual_alone.sh K VIEWS...; files residual-<views>-k<K>.*
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=results/stage2/noise
k=$1; shift
for v in "$@"; do
    stem="$out/residual-$v-k${k/./p}"
    [ -f "$stem.json" ] && continue
    python -m clamgen eval --table 2 --policy "residual-$v" --depth-noise-m "$k" --out "$stem"
done
