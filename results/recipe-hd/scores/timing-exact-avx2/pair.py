"""Per frame and round, the ratio and difference of B's stage times to A's (run.sh's output)."""
import glob
import json
import os
import statistics
import sys

out, a, b = sys.argv[1:4]


def load(name):
    times = {}
    for path in glob.glob(os.path.join(out, f"{name}-r*-clip_*.json")):
        rnd = os.path.basename(path).split("-")[1]
        for frame in json.load(open(path))["frames"]:
            times[(rnd, frame["clip"][-8:], frame["target"])] = frame["stages"]
    return times


A, B = load(a), load(b)
keys = sorted(set(A) & set(B))
for stage in ["total", "warp", "prior", "network", "infill"]:
    ratios = [B[k][stage]["median_ms"] / A[k][stage]["median_ms"] for k in keys]
    diffs = [B[k][stage]["median_ms"] - A[k][stage]["median_ms"] for k in keys]
    q = statistics.quantiles(ratios, n=4)
    print(f"{b}/{a} {stage:8s} ratio median {statistics.median(ratios):.3f} (IQR {q[0]:.3f}-{q[2]:.3f}), "
          f"difference median {statistics.median(diffs):+.1f} ms, {len(keys)} frame-rounds")
print("median over rounds by frame (ms):")
for frame in sorted({k[1:] for k in keys}):
    row = {stage: [statistics.median(T[k][stage]["median_ms"] for k in keys if k[1:] == frame) for T in (A, B)]
           for stage in ["infill", "total"]}
    print(f"  {frame[0]} t{frame[1]}: infill {row['infill'][0]:.1f} -> {row['infill'][1]:.1f}, total {row['total'][0]:.1f} -> {row['total'][1]:.1f}")
