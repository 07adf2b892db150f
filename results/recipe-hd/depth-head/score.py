"""Tables of the depth-head comparison (README.md): per seed, D-MSE x fill of the narrow head
(scores/NAME-sS from run.sh) beside the recipe's before it (the paper's head: results/recipe-hd/last9 as
scored in ../prior-scale at the default path), the mean and sd, the worst seed over the best, the
ratio to fill by clip and the worst frame; and the rule of README.md checked.
Usage: score.py [NAME] (default dh025)"""
import os
import statistics
import sys

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(here, "..", "prior-scale"))
from score import scores  # noqa: E402

name = sys.argv[1] if len(sys.argv) > 1 else "dh025"
seeds = [s for s in range(5) if os.path.isdir(os.path.join(here, "scores", f"{name}-s{s}"))]
prior = os.path.join(here, "..", "prior-scale")
sets = [
    ("hd", "blender-dev-hd (9 frames)", "hd_scale-auto.json", "hd-s{s}-auto.json", 0.6),
    ("dev12", "the 12 clips at 320x240 (36 frames)", "dev12.json", "dev12-s{s}-auto.json", 0.55),
    ("gen", "4 generated 1080p clips (12 frames)", "gen.json", "gen-s{s}-auto.json", None),
]
verdict = []
for key, title, mine, theirs, bar in sets:
    print(f"\n{title}\n")
    print("| depth head | " + " | ".join(f"seed {s}" for s in seeds) +
          " | mean ± sd | worst / best | worst frame x fill | by clip x fill (range over seeds) |")
    print("|---" * (len(seeds) + 5) + "|")
    means = {}
    for label, path in [(name, lambda s: os.path.join(here, "scores", f"{name}-s{s}", mine)),
                        ("paper's (last9)", lambda s: os.path.join(prior, theirs.format(s=s)))]:
        rows = [scores(path(s)) for s in seeds]
        ds = [r[0] for r in rows]
        means[label] = statistics.mean(ds)
        sd = f" ± {statistics.stdev(ds):.1f}" if len(ds) > 1 else ""
        clips = " / ".join(f"{min(r[2][c] for r in rows):.3f}-{max(r[2][c] for r in rows):.3f}"
                           for c in range(len(rows[0][2])))
        print(f"| {label} | " + " | ".join(f"{r[0]:.1f} ({r[0] / r[1]:.3f})" for r in rows) +
              f" | {means[label]:.1f}{sd} | {max(ds) / min(ds):.3f} | "
              f"{min(r[3] for r in rows):.2f}-{max(r[3] for r in rows):.2f} | {clips} |")
        if label == name and bar is not None:
            verdict.append(f"{key}: every seed at most {bar}x fill: {all(r[0] / r[1] <= bar for r in rows)}; "
                           f"worst/best within 5%: {max(ds) / min(ds) <= 1.05}")
            if key == "hd":
                verdict.append(f"hd: no frame behind fill: {all(r[3] <= 1 for r in rows)}")
    change = means[name] / means["paper's (last9)"] - 1
    print(f"\nmean {name} against the paper's head's: {100 * change:+.1f}%")
    if bar is not None:
        verdict.append(f"{key}: mean within +1% of the paper's head's: {change <= 0.01} ({100 * change:+.1f}%)")
print("\nThe rule of README.md, seeds " + ", ".join(map(str, seeds)) + ":\n")
for v in verdict:
    print(f"- {v}")
