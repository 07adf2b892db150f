#!/usr/bin/env bash
# Two (or more) ivp binaries timed in alternated rounds on the 9 blender-dev-hd frames, each frame
# `ivp bench frame --runs 5` (median of 5 warm runs by stage). Run from the repository root:
#   results/real-1080p/ab.sh OUT_DIR ROUNDS BINARY_A BINARY_B ...   (M=MODEL, HD=DIR)
set -euo pipefail
M=${M:-results/ablate/full/seed0/model.safetensors}; HD=${HD:-../shared/data/blender-dev-hd}
out=$1; rounds=${2:-2}; shift 2; mkdir -p $out
for round in $(seq $rounds); do
  for bin in "$@"; do
    for c in 0 1 2; do $bin -q bench frame --data $HD/clip_00$c --targets 3,4,5 --model $M --runs 5 > $out/$(basename $bin)-r$round-c$c.json; done
  done
done
python3 - $out $rounds "$@" <<'PY'
import json, statistics, sys, os
out, rounds, bins = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
for b in bins:
    for r in range(1, rounds + 1):
        fr = [f for c in range(3) for f in json.load(open(f"{out}/{os.path.basename(b)}-r{r}-c{c}.json"))["frames"]]
        st = lambda k: statistics.median([f["stages"][k]["median_ms"] for f in fr])
        tot = [f["stages"]["total"]["median_ms"] for f in fr]
        print(f"{os.path.basename(b):10s} round {r}: median {statistics.median(tot):6.1f} ms (range {min(tot):.0f}-{max(tot):.0f}); stage medians warp {st('warp'):.0f} prior {st('prior'):.0f} network {st('network'):.0f} infill {st('infill'):.0f}; read {statistics.median([f['pixels_read_fraction'] for f in fr]):.2f}; D-MSE {sum(f['d_mse'] for f in fr)/len(fr):.1f}")
PY
