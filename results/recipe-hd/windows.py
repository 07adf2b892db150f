#!/usr/bin/env python3
"""Would averaging the weights over the last steps, with the choice, make seeds agree?

Usage: windows.py CHECKPOINTS_DIR:WINDOWS_DIR...
CHECKPOINTS_DIR holds checkpoints.sh's JSON of one run (single checkpoints), WINDOWS_DIR that
of `checkpoints.sh RUN_DIR WINDOWS_DIR K` for K = 2, 3, 4 (means of K consecutive checkpoints).
Per run and per K: the candidate the validation (data/blender-dev, targets 3 to 11, 36 frames) chooses, its score on the 8 clips of
blender-dev-extra (which no choice saw), and the mean score of its members as single checkpoints.
Then per K over the runs: mean ± sd and worst/best on blender-dev-extra.
"""
import glob
import json
import os
import statistics
import sys

from validation_frames import mean_d_mse


def score(path):
    with open(path) as f:
        return mean_d_mse(json.load(f)["per_frame"])


def candidates(folder, pattern):
    """{last step: (validation, blender-dev-extra)} of the files dev-PATTERN-STEP.json."""
    found = {}
    for path in glob.glob(os.path.join(folder, f"extra-{pattern}.json")):
        name = os.path.basename(path)[len("extra-") : -len(".json")]
        step = int(name.split("-")[-1])
        found[step] = (score(os.path.join(folder, f"dev-{name}.json")), score(path))
    return found


def main(pairs):
    chosen = {1: [], 2: [], 3: [], 4: []}
    print("| run | K | chosen (last step) | validation | blender-dev-extra | its members, mean | all candidates, mean |")
    print("|---|---|---|---|---|---|---|")
    for pair in pairs:
        singles_dir, windows_dir = pair.split(":")
        singles = candidates(singles_dir, "[0-9]*")
        for k in (1, 2, 3, 4):
            found = singles if k == 1 else candidates(windows_dir, f"k{k}-*")
            if not found:
                continue
            step = min(found, key=lambda s: found[s][0])
            members = [singles[s][1] for s in range(step - 250 * (k - 1), step + 1, 250)]
            chosen[k].append(found[step][1])
            print(
                f"| {os.path.basename(os.path.normpath(windows_dir))} | {k} | {step} | {found[step][0]:.1f} | "
                f"{found[step][1]:.1f} | {statistics.mean(members):.1f} | {statistics.mean(v[1] for v in found.values()):.1f} |"
            )
    print()
    print("| K | blender-dev-extra, mean ± sd | worst / best |")
    print("|---|---|---|")
    for k, scores in chosen.items():
        if len(scores) < 2:
            continue
        print(f"| {k} | {statistics.mean(scores):.1f} ± {statistics.stdev(scores):.1f} | {max(scores) / min(scores):.3f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
