#!/usr/bin/env bash
# The 9 frames of blender-dev-hd timed end to end by `ivp bench frame` (seed 0 of the recipe, 5
# runs a frame), the prior at `--prior-scale auto` (4) and 2 in turn, the order swapped every
# round; then results/recipe-hd/timing_pairs.py prints each stage's paired difference over frames and rounds. The committed
# rounds: `run.sh OUT 2`, then `run.sh OUT2 4` with OUT2's rounds renumbered 3-6 here.
#   results/recipe-hd/prior-scale/timing-avx2/run.sh OUT ROUNDS; python3 results/recipe-hd/timing_pairs.py OUT pauto p2
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=$1; rounds=${2:-3}
hd=${HD:-../shared/data/blender-dev-hd}
m=results/recipe-hd/last9/seed0/model.safetensors
mkdir -p "$out"
for r in $(seq 1 "$rounds"); do
  order="auto 2"; [ $((r % 2)) -eq 0 ] && order="2 auto"
  for ps in $order; do
    for c in 0 1 2; do
      target/release/ivp -q bench frame --data "$hd/clip_00$c" --targets 3,4,5 --model "$m" --runs 5 --prior-scale "$ps" > "$out/r$r-p$ps-c$c.json"
    done
  done
done
