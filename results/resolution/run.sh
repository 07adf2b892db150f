#!/usr/bin/env bash
# The recipe's model (the `full` runs of results/ablate, one per seed) at 320x240 and 1920x1080,
# beside fill, oracle and Telea: writes scores_*.json here. Run from the repository's root:
#   results/resolution/run.sh [IVP_BINARY] [HD_CLIPS]
# IVP_BINARY defaults to target/release/ivp; HD_CLIPS to ../shared/data/blender-dev-hd (the
# 1080p Blender dev clip, targets 3 4 5; skipped when absent).
set -euo pipefail
ivp=${1:-target/release/ivp}
hd=${2:-../shared/data/blender-dev-hd}
out=results/resolution
models=()
for dir in results/ablate/full/seed*; do
    [ -f "$dir/model.safetensors" ] && models+=(--model "full-${dir##*/}=$dir/model.safetensors")
done
[ ${#models[@]} -gt 0 ] || { echo "no finished full runs in results/ablate/full" >&2; exit 1; }

# Generated held-out clips (seed 59297, as the ablation's): 4 at 320x240, 3 at 1080p.
[ -d results/ablate/held-out ] || "$ivp" --quiet generate --out results/ablate/held-out --seed 59297 --clips 4
[ -d $out/held-out-hd ] || "$ivp" --quiet generate --out $out/held-out-hd --seed 59297 --clips 3 --width 1920 --height 1080

score() { # NAME DATA SCALE EXTRA...
    local name=$1 data=$2 scale=$3; shift 3
    "$ivp" --quiet eval --data "$data" --scale "$scale" --json "$out/scores_${name}_scale-${scale}.json" "$@" "${models[@]}"
}
score blender-dev data/blender-dev auto --methods fill,oracle,telea
score generated-320x240 results/ablate/held-out auto --methods fill,oracle,telea
# At 1080p the default (auto) shrinks frames by 2; every factor from 1 to 5 for comparison.
for scale in auto 1 3 4 5; do
    methods=(--methods fill); [ $scale = auto ] && methods=(--methods fill,oracle,telea)
    score generated-1080p $out/held-out-hd $scale "${methods[@]}"
    if [ -d "$hd" ]; then score blender-dev-hd "$hd" $scale --targets 3,4,5 "${methods[@]}"; fi
done
