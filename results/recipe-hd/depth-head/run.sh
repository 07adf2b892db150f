#!/usr/bin/env bash
# The recipe with a narrower depth head (CONFIG, default dh025.toml: widths 4, 8, 4 instead of
# 16, 32, 16), trained for each seed in SEEDS and scored as the recipe is judged:
#   - `ivp train --synthetic --config CONFIG --seed S`, resumed where a run was cut short;
#   - score.sh at the default 1080p path and at --scale 1 (SCALES="auto 1"): the 12 clips at
#     320x240 and the 9 frames of blender-dev-hd; and the 4 generated 1080p clips of
#     prior-scale/run.sh.
# Run folders go to RUNS (default runs/), models and scores to this folder. From anywhere:
#   results/recipe-hd/depth-head/run.sh        (SEEDS="0 1", CONFIG=..., NAME=..., HD=..., GEN=...)
set -euo pipefail
here=results/recipe-hd/depth-head
cd "$(dirname "$0")/../../.."
config=${CONFIG:-$here/dh025.toml}
name=${NAME:-$(basename "$config" .toml)}
runs=${RUNS:-runs}
gen=${GEN:-/tmp/gen-hd}
ivp=${IVP:-target/release/ivp}
[ -d "$gen" ] || "$ivp" -q generate --out "$gen" --clips 4 --frames 6 --width 1920 --height 1080 --seed 59297
for s in ${SEEDS:-0 1 2 3 4}; do
  run=$runs/$name-s$s
  if [ ! -f "$run/model.safetensors" ]; then
    resume=""; [ -f "$run/config.toml" ] && resume="--resume"
    "$ivp" -q train --synthetic --config "$config" --seed "$s" --out "$run" $resume
  fi
  keep=$here/$name/seed$s
  mkdir -p "$keep"
  cp "$run"/{config.toml,metrics.csv,loss.png,model.safetensors} "$keep/"
  scores=$here/scores/$name-s$s
  SCALES=${SCALES:-auto 1} results/recipe-hd/score.sh "$keep/model.safetensors" "$scores"
  "$ivp" -q eval --data "$gen" --targets 3,4,5 --methods fill,ivp --model "$keep/model.safetensors" --json "$scores/gen.json" > /dev/null
done
