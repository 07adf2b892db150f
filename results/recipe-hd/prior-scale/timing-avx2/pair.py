"""Paired differences `--prior-scale auto` - `2` by stage over the frames and rounds of run.sh:
the median and quartiles in ms, and of the ratio."""
import collections
import glob
import json
import os
import statistics
import sys

out = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(__file__)
vals = collections.defaultdict(dict)
for f in glob.glob(os.path.join(out, "r*-p*-c*.json")):
    r, p, c = os.path.basename(f)[:-5].split("-")
    for frame in json.load(open(f))["frames"]:
        vals[(r, c, frame["target"])][p] = {k: v["median_ms"] for k, v in frame["stages"].items()}
pairs = [v for v in vals.values() if len(v) == 2]
print(f"{len(pairs)} frame pairs")
for stage in ["total", "warp", "prior", "network", "infill"]:
    d = [v["pauto"][stage] - v["p2"][stage] for v in pairs]
    ratio = [v["pauto"][stage] / v["p2"][stage] for v in pairs]
    q, qr = statistics.quantiles(d, n=4), statistics.quantiles(ratio, n=4)
    a = statistics.median(v["pauto"][stage] for v in pairs)
    b = statistics.median(v["p2"][stage] for v in pairs)
    print(f"| {stage} | {a:.1f} | {b:.1f} | {statistics.median(d):+.1f} ({q[0]:+.1f} to {q[2]:+.1f}) | "
          f"{statistics.median(ratio):.2f} ({qr[0]:.2f}-{qr[2]:.2f}) |")
