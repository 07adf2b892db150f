#!/usr/bin/env bash
# The mean of a run's checkpoints over a fixed window of steps (no choice by validation), scored
# as score.sh scores a model (results/recipe-hd/README.md, "Fixed windows").
# Usage, from the repository's root after `cargo build --release`:
#   results/recipe-hd/fixed_window.sh MODEL_OUT SCORES_DIR RUN_DIR:FIRST-LAST [RUN_DIR:FIRST-LAST ...]
# e.g. fixed_window.sh m.safetensors scores/w6 runs/recipe-s0:3750-5000 averages steps 3750, 4000,
# ..., 5000 of runs/recipe-s0 (checkpoints every 250 steps, kept: keep_checkpoints = 11); several
# RUN_DIR:FIRST-LAST average all their checkpoints together. Env: IVP, SCALES, HD as for score.sh.
set -euo pipefail
model=${1:?usage: fixed_window.sh MODEL_OUT SCORES_DIR RUN_DIR:FIRST-LAST ...}
scores=${2:?usage: fixed_window.sh MODEL_OUT SCORES_DIR RUN_DIR:FIRST-LAST ...}
shift 2
checkpoints=()
for window in "$@"; do
  run=${window%:*} range=${window##*:}
  for ((step = ${range%-*}; step <= ${range#*-}; step += ${EVERY:-250})); do
    checkpoints+=("$(printf '%s/checkpoints/step_%08d.safetensors' "$run" "$step")")
  done
done
"${IVP:-target/release/ivp}" -q export --checkpoint "${checkpoints[@]}" --out "$model"
"$(dirname "$0")/score.sh" "$model" "$scores"
