#!/usr/bin/env bash
# Table 2 rows with noisy depth (results/stage2/noise/README.md): the shipped residuals alone,
# in their hybrids and with the escapes, and the depth-map planners, on the 200 + 200 test
# tasks with Gaussian noise of sd K*z^2 m on every depth pixel they read (`--depth-noise-m`).
# Nothing is chosen on these runs. Usage: run.sh K VIEWS... (VIEWS: 3views 2views 1view;
# files <row>-<views>-k<K>.*); an evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=results/stage2/noise
k=$1; shift
for v in "$@"; do
    for row in residual hybrid escapes depth-rrt; do
        stem="$out/$row-$v-k${k/./p}"
        [ -f "$stem.json" ] && continue
        case $row in
            residual) args=(--policy "residual-$v") ;;
            hybrid) args=(--policy "residual-$v" --depth-hybrid) ;;
            escapes) args=(--policy "residual-$v" --depth-escapes) ;;
            depth-rrt) args=(--policy "depth-rrt-$v") ;;
        esac
        python -m clamgen eval --table 2 "${args[@]}" --depth-noise-m "$k" --out "$stem"
    done
done
