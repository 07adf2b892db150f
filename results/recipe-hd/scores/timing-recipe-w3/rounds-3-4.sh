#!/usr/bin/env bash
# The recipe's seed 0 before (recipe36: one checkpoint) and after (recipe-w3: a mean of three),
# timed in alternated rounds on the 9 frames of blender-dev-hd (HD=DIR, default
# ../shared/data/blender-dev-hd) by results/real-1080p/ab.sh, after `cargo build --release`.
set -euo pipefail
cd "$(dirname "$0")/../../../.."   # the repository root
for r in 3 4; do
  M=results/recipe-hd/recipe-w3/seed0/model.safetensors results/real-1080p/ab.sh results/recipe-hd/scores/timing-recipe-w3/new-r$r 1 target/release/ivp
  M=results/recipe-hd/recipe36/seed0/model.safetensors results/real-1080p/ab.sh results/recipe-hd/scores/timing-recipe-w3/old-r$r 1 target/release/ivp
done
