#!/usr/bin/env bash
# 1080p frames end to end, default path (far blur 0.5) and --far-blur 0, alternated, 2 rounds.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
m=results/recipe-hd/last9/seed0/model.safetensors
out=${OUT:-results/recipe-hd/scores/timing-farblur-avx2}
for round in 1 2; do
  for cfg in blur noblur; do
    extra=""; [[ $cfg == noblur ]] && extra="--far-blur 0"
    for clip in ../shared/data/blender-dev-hd/clip_*; do
      target/release/ivp -q bench frame --data "$clip" --targets 3,4,5 --model "$m" --runs 5 $extra > "$out/$cfg-r$round-$(basename $clip).json"
    done
    python3 - "$out" "$cfg" "$round" <<'PY'
import glob, json, os, statistics, sys
out, cfg, rnd = sys.argv[1:]
fr = [f for p in sorted(glob.glob(os.path.join(out, f"{cfg}-r{rnd}-clip_*.json"))) for f in json.load(open(p))["frames"]]
tot = [f["stages"]["total"]["median_ms"] for f in fr]
inf = [f["stages"]["infill"]["median_ms"] for f in fr]
net = [f["stages"]["network"]["median_ms"] for f in fr]
warp = [f["stages"]["warp"]["median_ms"] for f in fr]
print(f"{cfg} round {rnd}: frame median {statistics.median(tot):.1f} ms ({min(tot):.0f}-{max(tot):.0f}), infill {statistics.median(inf):.1f}, network {statistics.median(net):.1f}, warp {statistics.median(warp):.1f}")
PY
  done
done
