#!/usr/bin/env bash
# The recipe's five models at P = 1, 2, 3 passes (`--iterations`) on the 9 frames of
# blender-dev-hd, and at P = 2 on the 12 clips at 320x240 (P = 3 there: scores/farblur-sS).
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=${OUT:-results/recipe-hd/scores/iterations-avx2}
hd=${HD:-../shared/data/blender-dev-hd}
for s in 0 1 2 3 4; do
  m=results/recipe-hd/last9/seed$s/model.safetensors
  for p in 3 2 1; do
    target/release/ivp -q eval --data "$hd" --targets 3,4,5 --methods fill,ivp --model "$m" --iterations $p --json "$out/hd-s$s-p$p.json" > /dev/null
  done
  target/release/ivp -q eval --data data --methods fill,ivp --model "$m" --iterations 2 --json "$out/dev12-s$s-p2.json" > /dev/null
done
