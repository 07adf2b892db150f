#!/usr/bin/env bash
# Scores every kept checkpoint of one run on the real clips: data/blender-dev at targets 3 to 11
# (the validation of the recipe since 2026-12-06; its targets 6, 8, 10 are the validation before)
# and data/blender-dev-extra at 6, 8, 10 (clips no choice saw). checkpoints.py reads the JSON.
# With K above 1, scores instead the mean of every window of K consecutive kept checkpoints (what
# an average of the weights over the last steps, such as an EMA, would give) as
# OUT_DIR/{dev,extra}-kK-LASTSTEP.json, which windows.py reads.
# Usage, from the repository's root after `cargo build --release`:
#   results/recipe-hd/checkpoints.sh RUN_DIR OUT_DIR [K]
set -euo pipefail
run=${1:?usage: checkpoints.sh RUN_DIR OUT_DIR [K]}
out=${2:?usage: checkpoints.sh RUN_DIR OUT_DIR [K]}
k=${3:-1}
ivp=${IVP:-target/release/ivp}
mkdir -p "$out"
model=$(mktemp --suffix=.safetensors)
trap 'rm -f "$model"' EXIT
checkpoints=("$run"/checkpoints/step_*.safetensors)
for ((i = 0; i + k <= ${#checkpoints[@]}; i++)); do
  window=("${checkpoints[@]:i:k}")
  step=$(basename "${window[-1]}" .safetensors)
  step=${step#step_}
  name=$step
  ((k > 1)) && name=k$k-$step
  [[ -f $out/extra-$name.json ]] && continue
  "$ivp" -q export --checkpoint "${window[@]}" --out "$model" >/dev/null
  "$ivp" -q eval --data data/blender-dev --targets 3,4,5,6,7,8,9,10,11 --methods fill --model "$model" \
    --json "$out/dev-$name.json" >/dev/null
  "$ivp" -q eval --data data/blender-dev-extra --methods fill --model "$model" --json "$out/extra-$name.json" >/dev/null
done
