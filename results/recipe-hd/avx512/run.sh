#!/usr/bin/env bash
# The default recipe trained on a CPU with AVX-512 (gemm's AVX-512 kernels round differently from
# its AVX2 ones, so the same seed draws another model there than the AVX2-trained
# depth-head/dh025/seedS), for each seed in SEEDS, and scored as the recipe is judged (score.sh at
# the default 1080p path: the 12 clips at 320x240 and the 9 frames of blender-dev-hd). Each run's
# config.toml, metrics.csv (with its train wall), loss.png and model are kept here.
#   results/recipe-hd/avx512/run.sh         (SEEDS="0 1 2", RUNS=runs, HD=...)
set -euo pipefail
here=results/recipe-hd/avx512
cd "$(dirname "$0")/../../.."
grep -q avx512f /proc/cpuinfo || { echo "this CPU has no AVX-512: the runs would be the AVX2 ones" >&2; exit 1; }
ivp=${IVP:-target/release/ivp}
runs=${RUNS:-runs}
for s in ${SEEDS:-0 1 2}; do
  run=$runs/avx512-s$s
  if [ ! -f "$run/model.safetensors" ]; then
    resume=""; [ -f "$run/config.toml" ] && resume="--resume"
    /usr/bin/time -f "seed $s: train wall %e s" -a -o "$here/train_wall.txt" \
      "$ivp" -q train --synthetic --seed "$s" --out "$run" $resume
  fi
  keep=$here/seed$s
  mkdir -p "$keep"
  cp "$run"/{config.toml,metrics.csv,loss.png,model.safetensors} "$keep/"
  SCALES=${SCALES:-auto} results/recipe-hd/score.sh "$keep/model.safetensors" "$here/scores/seed$s"
done
