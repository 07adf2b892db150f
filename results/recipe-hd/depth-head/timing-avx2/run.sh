#!/usr/bin/env bash
# The 9 frames of blender-dev-hd timed end to end by `ivp bench frame` (5 runs a frame, the
# default path), two models in turn, the order swapped every round; then results/recipe-hd/timing_pairs.py prints each
# stage's paired difference over frames and rounds:
#   results/recipe-hd/depth-head/timing-avx2/run.sh OUT ROUNDS
#   python3 results/recipe-hd/timing_pairs.py OUT dh025 paper
# dh025: the recipe with the narrow depth head (depth-head/dh025/seed0); paper: the recipe's
# (last9/seed0), the paper's depth head.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=$1; rounds=${2:-3}
hd=${HD:-../shared/data/blender-dev-hd}
declare -A model=(
  [dh025]=results/recipe-hd/depth-head/dh025/seed0/model.safetensors
  [paper]=results/recipe-hd/last9/seed0/model.safetensors
)
mkdir -p "$out"
for r in $(seq 1 "$rounds"); do
  order="dh025 paper"; [ $((r % 2)) -eq 0 ] && order="paper dh025"
  for name in $order; do
    for c in 0 1 2; do
      target/release/ivp -q bench frame --data "$hd/clip_00$c" --targets 3,4,5 --model "${model[$name]}" --runs 5 > "$out/r$r-$name-c$c.json"
    done
  done
done
