#!/usr/bin/env python3
"""Writes results/resolution/resolution.md from the scores_*.json that run.sh wrote: each method's
D-MSE, D-SSIM, TC and ms/frame per dataset and scale, the model as mean +- sample std over the
seeds found (full-seed0, full-seed1, ...). Standard library only."""
import glob
import json
import os
import statistics

HERE = os.path.dirname(os.path.abspath(__file__))
DATASETS = [
    ("blender-dev", "Blender dev clips, 320x240 (data/blender-dev)"),
    ("generated-320x240", "generated held-out clips, 320x240 (seed 59297)"),
    ("blender-dev-hd", "Blender dev clip, 1920x1080 (blender-dev-hd, targets 3 4 5)"),
    ("generated-1080p", "generated held-out clips, 1920x1080 (seed 59297)"),
]
KEYS = [("d_mse", "D-MSE", 1), ("d_ssim", "D-SSIM", 3), ("tc", "TC", 1), ("ms_per_frame", "ms/frame", 0)]


def cell(values, digits):
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    mean = statistics.mean(values)
    if len(values) == 1:
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {statistics.stdev(values):.{digits}f}"


def rows(report, scale):
    methods = report["methods"]
    seeds = sorted(k for k in methods if k.startswith("full-seed"))
    fill = methods["fill"]["d_mse"]
    out = []
    for name in ["fill", "oracle", "telea"]:
        if name in methods and (scale == "auto" or name == "fill"):
            m = methods[name]
            out.append((name, [cell([m.get(k)], d) for k, _, d in KEYS], m["d_mse"] / fill))
    if seeds:
        label = f"ivp (full, {len(seeds)} seed{'s' if len(seeds) > 1 else ''}), scale {scale}"
        ratio = statistics.mean(methods[s]["d_mse"] for s in seeds) / fill
        out.append((label, [cell([methods[s].get(k) for s in seeds], d) for k, _, d in KEYS], ratio))
    return out


def main():
    lines = ["# The recipe's model at 320x240 and 1080p", "",
             "Made with `cargo build --release -p ivp-train && results/resolution/run.sh && "
             "python3 results/resolution/table.py` (the scores of `run.sh`, this table by `table.py`), "
             "on 2 cores. The model rows are the `full` runs of `results/ablate` (the default recipe, "
             "one per seed; since 2026-12-04 those trained with the fill guide, the default; the "
             "prior-guided runs before them are in results/recipe/prior-guide): mean ± sample "
             "standard deviation over the seeds. Scale `auto` is 1 at "
             "320x240 and 2 at 1080p (ALGORITHMS.md §6.7). D-MSE / fill compares with `fill` on the "
             "same frames; TC needs 12-frame clips (the 1080p Blender clip has 6 frames). ms/frame is "
             "`ivp eval`'s wall time (the run of 2026-12-04, binary of commit 9845b45, which made the fill "
             "guide the default, ran with nothing beside it; the machine is shared, so expect 10-20% "
             "between runs): PERFORMANCE.md splits the time by stage.", ""]
    for key, title in DATASETS:
        files = sorted(glob.glob(os.path.join(HERE, f"scores_{key}_scale-*.json")))
        if not files:
            continue
        scales = sorted((f.rsplit("scale-", 1)[1][:-5] for f in files), key=lambda s: (s != "auto", s))
        lines += [f"## {title}", "", "| method | " + " | ".join(h for _, h, _ in KEYS) + " | D-MSE / fill |",
                  "|---" * (len(KEYS) + 2) + "|"]
        for scale in scales:
            with open(os.path.join(HERE, f"scores_{key}_scale-{scale}.json")) as f:
                report = json.load(f)
            for i, (name, cells, ratio) in enumerate(rows(report, scale)):
                if scale != "auto" and i == 0:
                    continue  # fill once
                lines.append(f"| {name} | " + " | ".join(cells) + f" | {ratio:.3f} |")
        lines.append("")
    with open(os.path.join(HERE, "resolution.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
