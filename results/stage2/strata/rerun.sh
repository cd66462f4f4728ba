#!/usr/bin/env bash
# Session 50: the policies alone re-evaluated on the 200 blocked test tasks, every training
# seed whose checkpoint is committed, so each row records per task whether it collided and how
# many steps it took (rows measured before session 49 record success only). A description
# of committed policies on the committed test tasks; nothing is chosen on it.
#   bash results/stage2/strata/rerun.sh A   # 3 views: seeds 5 (shipped), 7, 8, 9
#   bash results/stage2/strata/rerun.sh B   # 2 and 1 views: seeds 5 (shipped), 11, 12
#   bash results/stage2/strata/rerun.sh C   # 3-view hybrids and escapes; RRT, depth RRT, IK
#   bash results/stage2/strata/rerun.sh D   # 2- and 1-view hybrids and escapes, 1-view planner + escapes
# The ways of acting take the committed rows' flags (`--depth-hybrid`; the escapes' shield
# flags as in `results/table2/escapes_residual-*.json`).
set -euo pipefail
cd "$(dirname "$0")/../../.."
OUT=results/stage2/strata
S=results/stage2/ensemble/seeds
ESC=(--depth-shield-m 0.01 --depth-shadow-m 0.05 --depth-shadow-behind-surfaces
  --depth-fine-size 128 --depth-escapes)
run() {  # policy, views word, stem, way of acting's words, its flags...
  clamgen eval --table 2 --families blocked --num-tasks 200 --policy "$1" \
    --name "CLAMGen, $2, student of the shipped recipe (ours), ${4:-alone}" --out "$OUT/$3" "${@:5}"
}
ckpt() {  # views, seed: the shipped policy for seed 5, else the committed seed checkpoint
  if [ "$2" = 5 ]; then case $1 in 3) echo residual-3views ;; 2) echo residual-2views ;;
    1) echo residual-1view ;; esac
  else echo "$S/d$1_seed$2_policy.pt"; fi
}
words() { if [ "$1" = 1 ]; then echo "1 RGBD view"; else echo "$1 RGBD views"; fi; }
ways() {  # views, seeds...: hybrid and escapes rows for each seed
  v=$1; shift
  for s in "$@"; do
    run "$(ckpt "$v" "$s")" "$(words "$v")" "hybrid${v}_seed$s" "+ depth shield and planner" --depth-hybrid
    run "$(ckpt "$v" "$s")" "$(words "$v")" "escapes${v}_seed$s" "+ depth shield, random escapes" "${ESC[@]}"
  done
}
case "$1" in
  A) run residual-3views "3 RGBD views" alone3_seed5
     for s in 7 8 9; do run "$S/d3_seed${s}_policy.pt" "3 RGBD views" "alone3_seed$s"; done ;;
  B) run residual-2views "2 RGBD views" alone2_seed5
     for s in 11 12; do run "$S/d2_seed${s}_policy.pt" "2 RGBD views" "alone2_seed$s"; done
     run residual-1view "1 RGBD view" alone1_seed5
     for s in 11 12; do run "$S/d1_seed${s}_policy.pt" "1 RGBD view" "alone1_seed$s"; done ;;
  C) ways 3 5 7 8 9
     for p in rrt depth-rrt-3views ik; do
       clamgen eval --table 2 --families blocked --num-tasks 200 --policy $p --out "$OUT/$p"
     done ;;
  D) ways 2 5 11 12; ways 1 5 11 12
     for s in 5 11 12; do
       run "$(ckpt 1 "$s")" "1 RGBD view" "escapes_planner1_seed$s" \
         "+ depth shield, planner, escapes where it finds none" "${ESC[@]}" --depth-planner
     done ;;
  *) echo "usage: rerun.sh A|B|C|D" >&2; exit 2 ;;
esac
