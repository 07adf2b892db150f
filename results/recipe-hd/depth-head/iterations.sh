#!/usr/bin/env bash
# Fewer passes with the narrow head: the five models of dh025/ on the 9 frames of blender-dev-hd at
# --iterations 2 (the default is 3), scored by `ivp eval` into scores/dh025-sS/hd_iter2.json.
#   results/recipe-hd/depth-head/iterations.sh       (HD=DIR, P=N to change)
set -euo pipefail
cd "$(dirname "$0")/../../.."
here=results/recipe-hd/depth-head
hd=${HD:-../shared/data/blender-dev-hd}
p=${P:-2}
for s in 0 1 2 3 4; do
  target/release/ivp -q eval --data "$hd" --targets 3,4,5 --methods fill --model "$here/dh025/seed$s/model.safetensors" \
    --iterations "$p" --json "$here/scores/dh025-s$s/hd_iter$p.json" > /dev/null
done
