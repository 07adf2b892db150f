#!/usr/bin/env python3
"""Which checkpoint each validation would choose, from checkpoints.sh's JSON.

Usage: checkpoints.py OUT_DIR...
Per run: every checkpoint's mean D-MSE (as `ivp eval` pools) on data/blender-dev at targets 6, 8,
10 (12 frames), at targets 3 to 11 (36 frames), and on the 8 clips of blender-dev-extra; the step
each of the two validations chooses (the lowest) and its blender-dev-extra score; the Spearman
rank correlation of each validation with blender-dev-extra over the checkpoints.
"""
import glob
import json
import os
import sys

from validation_frames import mean_d_mse, spearman

for out in sys.argv[1:]:
    rows = []
    for path in sorted(glob.glob(os.path.join(out, "extra-*.json"))):
        step = os.path.basename(path)[len("extra-") : -len(".json")]
        with open(os.path.join(out, f"dev-{step}.json")) as f:
            dev = json.load(f)["per_frame"]
        with open(path) as f:
            extra = mean_d_mse(json.load(f)["per_frame"])
        twelve = mean_d_mse([f for f in dev if f["target"] in (6, 8, 10)])
        rows.append((int(step), twelve, mean_d_mse(dev), extra))
    by12 = min(rows, key=lambda r: r[1])
    by36 = min(rows, key=lambda r: r[2])
    extra = [r[3] for r in rows]
    print(f"{out}: {len(rows)} checkpoints; 12 frames choose step {by12[0]} ({by12[3]:.1f} on blender-dev-extra), "
          f"36 frames step {by36[0]} ({by36[3]:.1f}); Spearman with blender-dev-extra: "
          f"12 frames {spearman([r[1] for r in rows], extra):.2f}, 36 frames {spearman([r[2] for r in rows], extra):.2f}")
    for step, twelve, all36, on_extra in rows:
        print(f"    step {step}: {twelve:.1f} / {all36:.1f} / {on_extra:.1f}")
