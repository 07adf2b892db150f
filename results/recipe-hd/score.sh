#!/usr/bin/env bash
# Scores one trained model the way the recipe is judged (results/recipe-hd/README.md):
#   - the 12 Blender clips at 320x240 (data/blender-dev + data/blender-dev-extra, targets 6, 8, 10),
#     pooled as `ivp eval` pools them, beside fill, telea and the oracle;
#   - the 3 Blender clips at 1920x1080 (blender-dev-hd, targets 3, 4, 5) at each 1080p scale in
#     SCALES (default "auto 1 3"), every frame's D-MSE kept (the JSON's per_frame).
# Usage, from the repository's root after `cargo build --release`:
#   results/recipe-hd/score.sh MODEL OUT_DIR
# Env: IVP (default target/release/ivp); HD (default ../shared/data/blender-dev-hd: 145 MB, not in
# the repository); SCALES; FLAGS (more flags for every `ivp eval`, e.g. "--far-blur 0").
set -euo pipefail
model=${1:?usage: score.sh MODEL OUT_DIR}
out=${2:?usage: score.sh MODEL OUT_DIR}
ivp=${IVP:-target/release/ivp}
hd=${HD:-../shared/data/blender-dev-hd}
mkdir -p "$out"
"$ivp" -q eval --data data --methods fill,telea,oracle --model "$model" ${FLAGS:-} --json "$out/dev12.json" >/dev/null
if [[ -d $hd ]]; then
  for scale in ${SCALES:-auto 1 3}; do
    "$ivp" -q eval --data "$hd" --targets 3,4,5 --methods fill,telea,oracle --model "$model" --scale "$scale" ${FLAGS:-} \
      --json "$out/hd_scale-$scale.json" >/dev/null
  done
else
  echo "no 1080p clips at $hd: scored at 320x240 only" >&2
fi
