#!/usr/bin/env bash
# The 12 clips at 320x240 (data/blender-dev and data/blender-dev-extra, targets 6, 8, 10) timed by
# `ivp bench frame` per clip, the narrow head (dh025/seed0) and the paper's (last9/seed0) in turn,
# the order swapped every round; files rR-NAME-cC.json with C the clip's index in `ls -d` order:
#   results/recipe-hd/depth-head/timing-avx2/dev12.sh OUT ROUNDS
#   python3 results/recipe-hd/timing_pairs.py OUT dh025 paper
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=$1; rounds=${2:-2}
declare -A model=(
  [dh025]=results/recipe-hd/depth-head/dh025/seed0/model.safetensors
  [paper]=results/recipe-hd/last9/seed0/model.safetensors
)
clips=(data/blender-dev/clip_* data/blender-dev-extra/clip_*)
mkdir -p "$out"
for r in $(seq 1 "$rounds"); do
  order="dh025 paper"; [ $((r % 2)) -eq 0 ] && order="paper dh025"
  for name in $order; do
    for c in "${!clips[@]}"; do
      target/release/ivp -q bench frame --data "${clips[$c]}" --targets 6,8,10 --model "${model[$name]}" --runs 5 > "$out/r$r-$name-c$c.json"
    done
  done
done
