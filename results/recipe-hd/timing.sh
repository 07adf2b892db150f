#!/usr/bin/env bash
# ms/frame of real 1080p frames end to end for two models, alternated over ROUNDS rounds (default 2),
# on a quiet machine: `ivp bench frame` on the 9 frames of blender-dev-hd (targets 3, 4, 5), median
# of 5 warm runs per frame; prints each round's median over the 9 frames and their range.
#   results/recipe-hd/timing.sh OUT_DIR MODEL_A MODEL_B [--scale 1]
set -euo pipefail
out=$1; a=$2; b=$3; shift 3
ivp=${IVP:-target/release/ivp}
hd=${HD:-../shared/data/blender-dev-hd}
mkdir -p "$out"
for round in $(seq 1 "${ROUNDS:-2}"); do
  for name in a b; do
    model=${!name}
    for clip in "$hd"/clip_*; do
      "$ivp" -q bench frame --data "$clip" --targets 3,4,5 --model "$model" --runs 5 "$@" > "$out/$name-round$round-$(basename "$clip").json"
    done
    python3 - "$out" "$name" "$round" "$model" <<'PY'
import glob, json, os, statistics, sys
out, name, rnd, model = sys.argv[1:]
totals = [f["stages"]["total"]["median_ms"] for p in sorted(glob.glob(os.path.join(out, f"{name}-round{rnd}-clip_*.json")))
          for f in json.load(open(p))["frames"]]
print(f"{model} round {rnd}: median {statistics.median(totals):.1f} ms over {len(totals)} frames, {min(totals):.0f}-{max(totals):.0f} by frame")
PY
  done
done
