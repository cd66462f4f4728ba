#!/usr/bin/env bash
# Acting in real time with a moving target on the Table 2 test tasks
# (results/stage2/shield/README.md, "Session 44: acting in real time"): the shipped residuals
# alone and in their hybrids, and the depth-map planners, an act longer than the control
# period holding the arm still. Usage: realtime.sh SPEED VIEWS... (files
# realtime/<row>-<views>-0p2.*; at SPEED 0, the static targets, the residuals alone are not
# run: files realtime/<row>-<views>-0.*); an evaluation whose JSON exists is skipped.
# The rows depth-rrt-track and hybrid-track at 0.2 m/s were measured before the planner
# expected its own latency (commit 7485b7c reproduces them); the rows *-latency since (the
# same commands; the planner's default after the session-44 validation).
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=results/stage2/shield/moving/realtime
speed=$1; shift
mkdir -p "$out"
for v in "$@"; do
    for row in depth-rrt-track-latency hybrid-track-latency depth-rrt-track hybrid-track residual; do
        stem="$out/$row-$v-${speed/./p}"
        [ -f "$stem.json" ] && continue
        [ "$speed" = 0 ] && [ "$row" != depth-rrt-track ] && [ "$row" != hybrid-track ] && continue
        case $row in
            residual) args=(--policy "residual-$v") ;;
            hybrid-track|hybrid-track-latency) args=(--policy "residual-$v" --depth-hybrid) ;;
            depth-rrt-track|depth-rrt-track-latency) args=(--policy "depth-rrt-$v") ;;
        esac
        python -m clamgen eval --table 2 "${args[@]}" --target-speed "$speed" --real-time --out "$stem"
    done
done
