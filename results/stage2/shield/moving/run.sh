#!/usr/bin/env bash
# A moving target on the Table 2 test tasks (results/stage2/shield/README.md, "A moving
# target on the test tasks"): the shipped residuals alone and in their hybrids, and the
# depth-map baselines, with the target moving at each speed. Usage: run.sh SPEED VIEWS...
# (e.g. run.sh 0.1 3views 2views 1view: files <row>-<views>-0p1.*); an evaluation whose JSON
# exists is skipped. Session 43 ran the rows residual, hybrid and depth-rrt (its planners then
# planned to where the target is: `--depth-track-m 0` now gives them); session 44 the rows
# depth-rrt-track and hybrid-track (the planners meeting the target, their default since).
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=results/stage2/shield/moving
speed=$1; shift
for v in "$@"; do
    for row in residual hybrid depth-rrt depth-rrt-track hybrid-track; do
        stem="$out/$row-$v-${speed/./p}"  # 0.1 -> 0p1: a dot would read as a file suffix
        [ -f "$stem.json" ] && continue
        case $row in
            residual) args=(--policy "residual-$v") ;;
            hybrid) args=(--policy "residual-$v" --depth-shield-m 0.01 --depth-planner
                          --depth-fine-size 128 --depth-track-m 0)
                    [ "$v" = 1view ] && args+=(--depth-shadow-m 0.05 --depth-shadow-behind-surfaces) ;;
            depth-rrt) args=(--policy "depth-rrt-$v" --depth-track-m 0) ;;
            depth-rrt-track) args=(--policy "depth-rrt-$v") ;;
            hybrid-track) args=(--policy "residual-$v" --depth-hybrid) ;;
        esac
        python -m clamgen eval --table 2 "${args[@]}" --target-speed "$speed" --out "$stem"
    done
done
