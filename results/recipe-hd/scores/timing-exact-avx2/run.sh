#!/usr/bin/env bash
# Alternated timing of ivp binaries on the 9 frames of blender-dev-hd (seed 0 of the recipe),
# the order rotated every round: OUT ROUNDS RUNS NAME=BINARY ... ; then pair.py OUT A B.
# The committed round: two binaries built from 8bb5883 (head) and from the commit that added
# this folder (new), each with `cargo build --release -p ivp-train` in its own worktree:
#   results/recipe-hd/scores/timing-exact-avx2/run.sh OUT 4 8 head=/tmp/ivp-head new=/tmp/ivp-new
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=$1; rounds=$2; runs=$3; shift 3
hd=${HD:-../shared/data/blender-dev-hd}
m=results/recipe-hd/last9/seed0/model.safetensors
mkdir -p "$out"
cfgs=("$@")
for round in $(seq 1 "$rounds"); do
  n=${#cfgs[@]}
  for k in $(seq 0 $((n - 1))); do
    cfg=${cfgs[$(( (k + round) % n ))]}
    name=${cfg%%=*}; bin=${cfg#*=}
    for clip in "$hd"/clip_*; do
      "$bin" -q bench frame --data "$clip" --targets 3,4,5 --model "$m" --runs "$runs" > "$out/$name-r$round-$(basename "$clip").json"
    done
  done
done
