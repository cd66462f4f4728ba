#!/usr/bin/env bash
# How fast each arrives (results/stage2/shield/README.md, "How fast each arrives"): the
# shipped residuals alone and in their hybrids, and the depth-map baselines, on the Table 2
# test tasks, recording each task's steps and tip path. Usage: run.sh VIEWS... (3views 2views
# 1view); an evaluation whose JSON exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=results/stage2/shield/arrival
for v in "$@"; do
    for row in residual hybrid depth-rrt; do
        [ -f "$out/$row-$v.json" ] && continue
        case $row in
            residual) args=(--policy "residual-$v") ;;
            hybrid) args=(--policy "residual-$v" --depth-hybrid) ;;
            depth-rrt) args=(--policy "depth-rrt-$v") ;;
        esac
        python -m clamgen eval --table 2 "${args[@]}" --out "$out/$row-$v"
    done
done
