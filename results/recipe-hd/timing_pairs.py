"""Paired differences A - B by stage over the frames and rounds of two settings or models timed in
alternated rounds by `ivp bench frame` (files rR-NAME-cC.json, as the timing-avx2/run.sh scripts
write them): the medians of A and B, the median difference with its quartiles in ms, the ratio's,
and each clip's median frame.
Usage: results/recipe-hd/timing_pairs.py OUT A B"""
import collections
import glob
import json
import os
import statistics
import sys

out, a, b = sys.argv[1:4]
vals = collections.defaultdict(dict)
for f in glob.glob(os.path.join(out, "r*-*-c*.json")):
    r, name, c = os.path.basename(f)[:-5].split("-")
    for frame in json.load(open(f))["frames"]:
        vals[(r, c, frame["target"])][name] = {k: v["median_ms"] for k, v in frame["stages"].items()}
pairs = [v for v in vals.values() if a in v and b in v]
print(f"{len(pairs)} frame pairs")
print(f"| stage | {a} (ms) | {b} (ms) | paired difference (IQR) | ratio (IQR) |")
print("|---|---|---|---|---|")
for stage in ["total", "warp", "prior", "network", "infill"]:
    d = [v[a][stage] - v[b][stage] for v in pairs]
    # Frames where the stage did not run in B (no network pass: all holes thin) have no ratio.
    ratio = [v[a][stage] / v[b][stage] for v in pairs if v[b][stage] > 0]
    q, qr = statistics.quantiles(d, n=4), statistics.quantiles(ratio, n=4)
    ma = statistics.median(v[a][stage] for v in pairs)
    mb = statistics.median(v[b][stage] for v in pairs)
    print(f"| {stage} | {ma:.1f} | {mb:.1f} | {statistics.median(d):+.1f} ({q[0]:+.1f} to {q[2]:+.1f}) | "
          f"{statistics.median(ratio):.2f} ({qr[0]:.2f}-{qr[2]:.2f}) |")
by_clip = collections.defaultdict(lambda: collections.defaultdict(list))
for (r, c, t), v in vals.items():
    for name in (a, b):
        if name in v:
            by_clip[c][name].append(v[name]["total"])
for c in sorted(by_clip):
    print(f"clip {c}: " + ", ".join(f"{n} {statistics.median(by_clip[c][n]):.1f} ms" for n in (a, b)))
