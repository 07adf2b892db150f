"""Tables of the prior-scale comparison (README.md) from the JSON of run.sh: D-MSE by seed at
`--prior-scale auto` and 2, x fill, the mean and sd, the worst seed over the best, the ratio to
fill by clip (pooled over the clip's frames, weighed by disocclusion pixels, as `ivp eval` pools
frames) and the worst frame."""
import collections
import json
import os
import statistics
import sys


def scores(path):
    d = json.load(open(path))
    fill = d["methods"]["fill"]["d_mse"]
    ivp = d["methods"]["ivp"]["d_mse"]
    by_clip = collections.defaultdict(lambda: [0.0, 0.0])
    worst = 0.0
    for f in d["per_frame"]:
        a, b, n = f["d_mse"]["ivp"], f["d_mse"]["fill"], f["disocclusion_pixels"]
        if a is None or not n:
            continue
        by_clip[f["clip"]][0] += n * a
        by_clip[f["clip"]][1] += n * b
        worst = max(worst, a / b)
    clips = [a / b for _, (a, b) in sorted(by_clip.items())]
    return ivp, fill, clips, worst, d["methods"]["ivp"]["ms_per_frame"]


def main(out):
    for data, name in [("hd", "blender-dev-hd (9 frames)"), ("gen", "4 generated 1080p clips (12 frames)"),
                       ("dev12", "the 12 clips at 320x240 (36 frames)")]:
        print(f"\n{name}\n")
        print("| --prior-scale | " + " | ".join(f"seed {s}" for s in range(5)) +
              " | mean ± sd | worst / best | worst frame x fill | ms/frame (`ivp eval`) |")
        print("|---" * 10 + "|")
        for p in ["auto", "2"]:
            rows = [scores(os.path.join(out, f"{data}-s{s}-{p}.json")) for s in range(5)]
            ds = [r[0] for r in rows]
            cells = [f"{r[0]:.1f} ({r[0] / r[1]:.3f})" for r in rows]
            ms = [r[4] for r in rows]
            print(f"| {p} | " + " | ".join(cells) + f" | {statistics.mean(ds):.1f} ± {statistics.stdev(ds):.1f} | "
                  f"{max(ds) / min(ds):.3f} | {min(r[3] for r in rows):.2f}-{max(r[3] for r in rows):.2f} | "
                  f"{min(ms):.0f}-{max(ms):.0f} |")
        if data != "dev12":
            print("\nby clip, x fill, seeds 0-4 (auto against 2):\n")
            for p in ["auto", "2"]:
                rows = [scores(os.path.join(out, f"{data}-s{s}-{p}.json")) for s in range(5)]
                n = len(rows[0][2])
                spans = [f"{min(r[2][c] for r in rows):.3f}-{max(r[2][c] for r in rows):.3f}" for c in range(n)]
                print(f"- {p}: " + " / ".join(spans))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(__file__))
