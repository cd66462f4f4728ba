#!/usr/bin/env bash
# Session 48's control: obstacle-blind IK interpolation (no vision, no learning) through the
# same depth wrappers as the residual's base in session 42 (base_control.md), on the Table 2
# test tasks; nothing is chosen on these rows. Two lanes, one per argument list:
#   results/stage2/shield/ik_control.sh hybrid:3 hybrid:2 hybrid:1 &
#   results/stage2/shield/ik_control.sh escapes:3 escapes:2 escapes:1 escapes_planner:1 &
# A row whose file exists is skipped (a killed lane goes on where it stopped).
set -euo pipefail
cd "$(dirname "$0")/../../.."
CLAMGEN=${CLAMGEN:-.venv/bin/clamgen}
for item in "$@"; do
  wrapper=${item%%:*}
  views=${item##*:}
  suffix=$([ "$views" = 1 ] && echo 1view || echo "${views}views")
  out=results/table2/ik_through_${wrapper}_${suffix}
  [ -f "$out.json" ] && continue
  case $wrapper in
    hybrid) flags=(--depth-hybrid) ;;
    escapes) flags=(--depth-escapes) ;;
    escapes_planner) flags=(--depth-escapes --depth-planner) ;;
    *) echo "unknown wrapper $wrapper" >&2; exit 2 ;;
  esac
  MUJOCO_GL=${MUJOCO_GL:-egl} "$CLAMGEN" eval --table 2 --policy ik --depth-views "$views" \
    "${flags[@]}" --out "$out"
done
