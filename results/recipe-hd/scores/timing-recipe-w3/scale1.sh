#!/usr/bin/env bash
# Seed 0 of the recipe (a mean of three checkpoints) at 1080p with the network at full size
# (`--scale 1`), two rounds of `ivp bench frame` on the 9 frames of blender-dev-hd, after
# `cargo build --release` (HD=DIR, default ../shared/data/blender-dev-hd).
set -euo pipefail
cd "$(dirname "$0")/../../../.."   # the repository root
hd=${HD:-../shared/data/blender-dev-hd}
out=results/recipe-hd/scores/timing-recipe-w3/scale1
mkdir -p $out
for r in 1 2; do
  for c in 0 1 2; do
    target/release/ivp -q bench frame --data $hd/clip_00$c --targets 3,4,5 --model results/recipe-hd/recipe-w3/seed0/model.safetensors \
      --runs 5 --scale 1 > $out/r$r-c$c.json
  done
done
