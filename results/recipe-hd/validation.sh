#!/usr/bin/env bash
# Scores a model on the validation set a training run prints (validation.rs: the generated clips of
# `validation_seed` 20261204, 8 at 320x240 and 2 at 1920x1080), with the binary as it is now, so
# that models trained by older binaries are compared on the same footing. Writes OUT_DIR/val320.json
# and OUT_DIR/valhd.json (`ivp eval` JSON, beside `fill`).
# Usage, from the repository's root after `cargo build --release`:
#   results/recipe-hd/validation.sh MODEL OUT_DIR
# Env: IVP (default target/release/ivp); SET (default /tmp/ivp-validation-set: rendered once, 40 s).
set -euo pipefail
model=${1:?usage: validation.sh MODEL OUT_DIR}
out=${2:?usage: validation.sh MODEL OUT_DIR}
ivp=${IVP:-target/release/ivp}
set_dir=${SET:-/tmp/ivp-validation-set}
if [[ ! -d $set_dir/hd ]]; then
  "$ivp" -q generate --out "$set_dir/small" --clips 8 --seed 20261204 >/dev/null
  # The run's 1080p clips are clips 8 and 9 of the same seed (after the 8 small ones).
  "$ivp" -q generate --out "$set_dir/hd-all" --clips 10 --frames 6 --width 1920 --height 1080 --seed 20261204 >/dev/null
  mkdir -p "$set_dir/hd.tmp"
  ln -s "$set_dir/hd-all/clip_0008" "$set_dir/hd-all/clip_0009" "$set_dir/hd.tmp/"
  mv "$set_dir/hd.tmp" "$set_dir/hd"
fi
mkdir -p "$out"
"$ivp" -q eval --data "$set_dir/small" --methods fill --model "$model" --json "$out/val320.json" >/dev/null
"$ivp" -q eval --data "$set_dir/hd" --targets 3,4,5 --methods fill --model "$model" --json "$out/valhd.json" >/dev/null
