#!/usr/bin/env bash
# The temporal prior measured on frames shrunk by 4 at 1080p (`--prior-scale auto`, the default
# since this folder) against 2 (`--prior-scale 2`, the default before: the network's factor),
# the recipe's five models (results/recipe-hd/last9), scored by `ivp eval`:
#   - blender-dev-hd, 9 frames (targets 3, 4, 5), at both;
#   - 4 generated 1080p clips (targets 3, 4, 5), at both;
#   - the 12 clips at 320x240 (data/), where auto keeps the prior at full size, and at 2.
# Then score.py prints the tables of README.md. Run from anywhere:
#   results/recipe-hd/prior-scale/run.sh      (HD=DIR, GEN=DIR, OUT=DIR to change where)
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=${OUT:-results/recipe-hd/prior-scale}
hd=${HD:-../shared/data/blender-dev-hd}
gen=${GEN:-/tmp/gen-hd}
ivp=${IVP:-target/release/ivp}
[ -d "$gen" ] || "$ivp" -q generate --out "$gen" --clips 4 --frames 6 --width 1920 --height 1080 --seed 59297
for s in 0 1 2 3 4; do
  m=results/recipe-hd/last9/seed$s/model.safetensors
  for p in auto 2; do
    "$ivp" -q eval --data "$hd" --targets 3,4,5 --methods fill,ivp --model "$m" --prior-scale $p --json "$out/hd-s$s-$p.json" > /dev/null
    "$ivp" -q eval --data "$gen" --targets 3,4,5 --methods fill,ivp --model "$m" --prior-scale $p --json "$out/gen-s$s-$p.json" > /dev/null
    "$ivp" -q eval --data data --methods fill,ivp --model "$m" --prior-scale $p --json "$out/dev12-s$s-$p.json" > /dev/null
  done
done
python3 "$(dirname "$0")/score.py" "$out"
