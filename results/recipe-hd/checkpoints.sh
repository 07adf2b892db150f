#!/usr/bin/env bash
# Scores every kept checkpoint of one run on the real clips: data/blender-dev at targets 3 to 11
# (the validation of the recipe since 2026-12-06; its targets 6, 8, 10 are the validation before)
# and data/blender-dev-extra at 6, 8, 10 (clips no choice saw). checkpoints.py reads the JSON.
# Usage, from the repository's root after `cargo build --release`:
#   results/recipe-hd/checkpoints.sh RUN_DIR OUT_DIR
set -euo pipefail
run=${1:?usage: checkpoints.sh RUN_DIR OUT_DIR}
out=${2:?usage: checkpoints.sh RUN_DIR OUT_DIR}
ivp=${IVP:-target/release/ivp}
mkdir -p "$out"
model=$(mktemp --suffix=.safetensors)
trap 'rm -f "$model"' EXIT
for checkpoint in "$run"/checkpoints/step_*.safetensors; do
  step=$(basename "$checkpoint" .safetensors)
  step=${step#step_}
  [[ -f $out/extra-$step.json ]] && continue
  "$ivp" -q export --checkpoint "$checkpoint" --out "$model" >/dev/null
  "$ivp" -q eval --data data/blender-dev --targets 3,4,5,6,7,8,9,10,11 --methods fill --model "$model" \
    --json "$out/dev-$step.json" >/dev/null
  "$ivp" -q eval --data data/blender-dev-extra --methods fill --model "$model" --json "$out/extra-$step.json" >/dev/null
done
