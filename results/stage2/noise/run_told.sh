#!/usr/bin/env bash
# Table 2 rows with noisy depth, the wrappers' map told the noise model
# (results/stage2/noise/README.md): the shipped residuals in their hybrids and with the escapes,
# and the depth-map planners, with `--depth-noise-model-m K` beside `--depth-noise-m K`.
# Usage: run_told.sh K VIEWS... (VIEWS: 3views 2views 1view; files <row>-told-<views>-k<K>.*
# as <row>-<views>-k<K>.* of run.sh); an evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=results/stage2/noise
k=$1; shift
for v in "$@"; do
    for row in hybrid-told escapes-told depth-rrt-told; do
        stem="$out/$row-$v-k${k/./p}"
        [ -f "$stem.json" ] && continue
        case $row in
            hybrid-told) args=(--policy "residual-$v" --depth-hybrid --depth-noise-model-m "$k") ;;
            escapes-told) args=(--policy "residual-$v" --depth-escapes --depth-noise-model-m "$k") ;;
            depth-rrt-told) args=(--policy "depth-rrt-$v" --depth-noise-model-m "$k") ;;
        esac
        python -m clamgen eval --table 2 "${args[@]}" --depth-noise-m "$k" --out "$stem"
    done
done
