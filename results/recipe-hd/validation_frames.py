#!/usr/bin/env python3
"""How well the real-clip validation ranks models, by how many frames it scores.

Usage: validation_frames.py SCORES_DIR...
Each SCORES_DIR holds one model's dev12.json (score.sh: the 12 clips at targets 6, 8, 10) and
blender-dev-other-targets.json (`ivp eval --data data/blender-dev --targets 3,4,5,7,9,11
--methods fill --model MODEL --json ...`). Prints per model the mean D-MSE over the frames with
disocclusions (as `ivp eval` pools) of data/blender-dev at targets 6, 8, 10 (the validation of
the runs that made these models), at the other six targets, at all nine, and of the 8 clips of
blender-dev-extra; then, per family (the name before "-sN") and over all, the Spearman rank
correlation of each of the three with blender-dev-extra.
"""
import json
import os
import sys

from table import spearman


def mean_d_mse(frames):
    scores = [f["d_mse"]["ivp"] for f in frames if f["disocclusion_pixels"] and f["d_mse"]["ivp"] is not None]
    return sum(scores) / len(scores)


def main(dirs):
    rows = []
    for d in dirs:
        name = os.path.basename(os.path.normpath(d))
        with open(os.path.join(d, "dev12.json")) as f:
            twelve = json.load(f)["per_frame"]
        with open(os.path.join(d, "blender-dev-other-targets.json")) as f:
            other = json.load(f)["per_frame"]
        dev = [f for f in twelve if f["clip"].startswith("blender-dev/")]
        extra = [f for f in twelve if f["clip"].startswith("blender-dev-extra/")]
        rows.append((name, mean_d_mse(dev), mean_d_mse(other), mean_d_mse(dev + other), mean_d_mse(extra)))

    print("| model | blender-dev, targets 6, 8, 10 | the other 6 targets | all 9 targets | blender-dev-extra |")
    print("|---|---|---|---|---|")
    for name, *scores in rows:
        print(f"| {name} | " + " | ".join(f"{s:.1f}" for s in scores) + " |")
    print()
    print("| models | n | Spearman with blender-dev-extra: targets 6, 8, 10 | other 6 | all 9 |")
    print("|---|---|---|---|---|")
    families = sorted({r[0].rsplit("-s", 1)[0] for r in rows})
    for family in families + ["all"]:
        group = [r for r in rows if family == "all" or r[0].rsplit("-s", 1)[0] == family]
        if len(group) < 3:
            continue
        extra = [r[4] for r in group]
        cells = " | ".join(f"{spearman([r[i] for r in group], extra):.2f}" for i in (1, 2, 3))
        print(f"| {family} | {len(group)} | {cells} |")


if __name__ == "__main__":
    main(sys.argv[1:])
