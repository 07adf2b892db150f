#!/usr/bin/env bash
# The time of real 1080p frames end to end (issue 30): `ivp bench frame` on every target of the
# three blender-dev-hd clips (targets 3, 4, 5: 9 frames), by stage, with the hole fraction, the
# pixels the tiles read and each frame's D-MSE beside fill's; then the generated 1080p frame of
# `ivp bench frame` for comparison. Run from the repository's root on a quiet machine:
#   results/real-1080p/run.sh [MODEL]      (HD=DIR for the clips, default ../shared/data/blender-dev-hd;
#                                          OUT=DIR for the JSON, default results/real-1080p)
set -euo pipefail
model=${1:-results/ablate/full/seed0/model.safetensors}
ivp=${IVP:-target/release/ivp}
hd=${HD:-../shared/data/blender-dev-hd}
out=${OUT:-results/real-1080p}
mkdir -p "$out"
for clip in "$hd"/clip_*; do
  "$ivp" -q bench frame --data "$clip" --targets 3,4,5 --model "$model" --runs 5 > "$out/$(basename "$clip").json"
done
"$ivp" -q bench frame --model "$model" --runs 5 > "$out/generated.json"
python3 - "$out" <<'PY'
import json, statistics, sys, glob, os
out = sys.argv[1]
frames = [f for p in sorted(glob.glob(os.path.join(out, "clip_*.json"))) for f in json.load(open(p))["frames"]]
print("| clip | target | holes (% of frame) | pixels read (x frame seen) | warp | prior | network | infill | total ms | D-MSE (fill) |")
print("|---|---|---|---|---|---|---|---|---|---|")
for f in frames:
    s = {k: v["median_ms"] for k, v in f["stages"].items()}
    print(f"| {os.path.basename(f['clip'])} | {f['target']} | {100 * f['hole_fraction']:.2f} | {f['pixels_read_fraction']:.2f} | "
          f"{s['warp']:.0f} | {s['prior']:.0f} | {s['network']:.0f} | {s['infill']:.0f} | {s['total']:.0f} | "
          f"{f['d_mse']:.0f} ({f['d_mse_fill']:.0f}) |")
totals = [f["stages"]["total"]["median_ms"] for f in frames]
print(f"\n9 frames: median {statistics.median(totals):.0f} ms, range {min(totals):.0f}-{max(totals):.0f} ms")
g = json.load(open(os.path.join(out, "generated.json")))
print(f"generated frame: total {g['stages']['total']['median_ms']:.0f} ms, network {g['stages']['network']['median_ms']:.0f} ms, "
      f"holes {100 * g['hole_fraction']:.2f}%, pixels read {g['pixels_read_fraction']:.2f}")
PY
