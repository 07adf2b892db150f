#!/usr/bin/env python3
"""Tables of the recipe's seeds from the JSON that score.sh writes (results/recipe-hd/README.md).

Usage: table.py NAME=SCORES_DIR[:RUN_DIR] ...
SCORES_DIR holds dev12.json and hd_scale-*.json of one model; RUN_DIR (optional) its training run,
whose metrics.csv gives the validation the run printed for its model (the row of the step in
RUN_DIR/model.safetensors's metadata, else the last; validation.sh's val320.json and valhd.json in
SCORES_DIR, the generated set scored by the current binary, take precedence). Prints markdown: per
model, D-MSE and its ratio to fill on the 12 clips at 320x240 and on the 8 of blender-dev-extra
among them (with the worst clip and how many clips are worse than fill) and on the 1080p clips at
every scale scored (the worst frame, every clip), ms/frame; then mean +- sd over the models (also of
D-SSIM and temporal consistency), the
worst against the best, and the rank agreement (Spearman) of the printed validations (generated
frames; real clips, with --validation-data) with the 12 clips, the 8 and the 1080p clips.
"""
import csv
import glob
import json
import os
import statistics
import sys


def load(path):
    with open(path) as f:
        return json.load(f)


def model_scores(report):
    (name,) = [n for n in report["methods"] if n not in ("fill", "telea", "oracle", "copy", "warp")]
    return name, report["methods"][name], report["methods"]["fill"]


def worst_frame(report, name):
    """Largest ratio of the model's D-MSE to fill's over the frames with disocclusions."""
    ratios = [
        (r["d_mse"][name] / r["d_mse"]["fill"], f'{r["clip"]} t{r["target"]}')
        for r in report.get("per_frame", [])
        if r["d_mse"].get(name) is not None and r["d_mse"]["fill"]
    ]
    return max(ratios) if ratios else (float("nan"), "-")


def per_clip(report, name):
    clips = {}
    for r in report.get("per_frame", []):
        if r["d_mse"].get(name) is not None:
            m, f = clips.setdefault(r["clip"], ([], []))
            m.append(r["d_mse"][name])
            f.append(r["d_mse"]["fill"])
    return {c: statistics.mean(m) / statistics.mean(f) for c, (m, f) in sorted(clips.items())}


def model_step(run_dir):
    """The step whose parameters RUN_DIR/model.safetensors holds (its `ivp.step` metadata), if any."""
    path = os.path.join(run_dir, "model.safetensors")
    if not os.path.isfile(path):
        return None
    with open(path, "rb") as f:
        header = json.loads(f.read(int.from_bytes(f.read(8), "little")))
    step = header.get("__metadata__", {}).get("ivp.step")
    return int(step) if step is not None else None


def model_row(run_dir, column):
    """The row of metrics.csv that validated the run's model (its step's; else the last) with `column`."""
    rows = [r for r in csv.DictReader(open(os.path.join(run_dir, "metrics.csv"))) if r.get(column)]
    step = model_step(run_dir)
    chosen = [r for r in rows if int(r["step"]) == step]
    return (chosen or rows or [None])[-1]


def last_validation(run_dir):
    r = model_row(run_dir, "val_d_mse")
    if r is None:
        return None
    small = float(r["val_d_mse"]) / float(r["fill_d_mse"])
    large = float(r["val_hd_d_mse"]) / float(r["fill_hd_d_mse"]) if r.get("val_hd_d_mse") else float("nan")
    return small, large


def last_real_validation(run_dir):
    """The model's validation on real clips (`--validation-data`), as a ratio to fill, if logged."""
    r = model_row(run_dir, "val_real_d_mse")
    return float(r["val_real_d_mse"]) / float(r["fill_real_d_mse"]) if r else None


def pooled(report, name, prefix):
    """D-MSE of `name` over the frames of the clips whose name starts with `prefix`, pooled as
    `ivp eval` pools: the mean over frames with disocclusions."""
    return statistics.mean(r["d_mse"][name] for r in report["per_frame"]
                           if r["clip"].startswith(prefix) and r["d_mse"].get(name) is not None)


def recomputed_validation(scores_dir):
    """The run's validation recomputed by validation.sh (val320.json, valhd.json), if there."""
    paths = [os.path.join(scores_dir, f) for f in ("val320.json", "valhd.json")]
    if not all(os.path.isfile(p) for p in paths):
        return None
    ratios = []
    for p in paths:
        _, m, fill = model_scores(load(p))
        ratios.append(m["d_mse"] / fill["d_mse"])
    return tuple(ratios)


def spearman(a, b):
    def ranks(v):
        order = sorted(range(len(v)), key=lambda i: v[i])
        r = [0.0] * len(v)
        for k, i in enumerate(order):
            r[i] = k
        return r
    ra, rb = ranks(a), ranks(b)
    n = len(a)
    if n < 2:
        return float("nan")
    d = sum((x - y) ** 2 for x, y in zip(ra, rb))
    return 1 - 6 * d / (n * (n * n - 1))


def main(args):
    rows = []
    scales = set()
    for arg in args:
        name, _, dirs = arg.partition("=")
        scores_dir, _, run_dir = dirs.partition(":")
        row = {"name": name, "hd": {}}
        dev12 = load(os.path.join(scores_dir, "dev12.json"))
        mname, m, fill = model_scores(dev12)
        row["dev12"] = (m["d_mse"], fill["d_mse"], m["ms_per_frame"])
        row["other"] = {"320x240 D-SSIM": m["d_ssim"], "320x240 TC": m["tc"]}
        row["extra8"] = (pooled(dev12, mname, "blender-dev-extra/"), pooled(dev12, "fill", "blender-dev-extra/"))
        clips = per_clip(dev12, mname)
        worst = max(clips.items(), key=lambda kv: kv[1])
        row["dev12_clips"] = (worst[0], worst[1], sum(v > 1 for v in clips.values()), len(clips))
        for path in sorted(glob.glob(os.path.join(scores_dir, "hd_scale-*.json"))):
            scale = path.rsplit("hd_scale-", 1)[1][:-5]
            scales.add(scale)
            report = load(path)
            mname, m, fill = model_scores(report)
            row["hd"][scale] = (m["d_mse"], fill["d_mse"], m["ms_per_frame"], worst_frame(report, mname),
                                per_clip(report, mname))
            row["other"][f"1080p --scale {scale} D-SSIM"] = m["d_ssim"]
        row["validation"] = recomputed_validation(scores_dir) or (last_validation(run_dir) if run_dir else None)
        row["real_validation"] = last_real_validation(run_dir) if run_dir else None
        rows.append(row)
    scales = sorted(scales, key=lambda s: (s != "auto", s))

    head = ("| model | 320x240, 12 clips: D-MSE (x fill) | of them the 8 of blender-dev-extra | worst clip (x fill) "
            "| clips worse than fill | ms |")
    rule = "|---|---|---|---|---|---|"
    for s in scales:
        head += f" 1080p --scale {s}: D-MSE (x fill) | worst frame (x fill) | per clip (x fill) | ms |"
        rule += "---|---|---|---|"
    head += " validation printed (x fill: 320x240 / 1080p) |"
    rule += "---|"
    print(head)
    print(rule)
    for r in rows:
        d, f, ms = r["dev12"]
        wc, wr, worse, n = r["dev12_clips"]
        e, ef = r["extra8"]
        line = f'| {r["name"]} | {d:.1f} ({d / f:.3f}) | {e:.1f} ({e / ef:.3f}) | {wr:.2f} ({wc}) | {worse} of {n} | {ms:.1f} |'
        for s in scales:
            if s in r["hd"]:
                d, f, ms, (wr, wf), clips = r["hd"][s]
                pc = " / ".join(f"{v:.2f}" for v in clips.values())
                line += f" {d:.1f} ({d / f:.3f}) | {wr:.2f} ({wf}) | {pc} | {ms:.0f} |"
            else:
                line += " - | - | - | - |"
        v = r["validation"]
        line += f" {v[0]:.3f} / {v[1]:.3f} |" if v else " - |"
        print(line)

    def summary(label, values):
        if len(values) < 2:
            return
        mean, sd = statistics.mean(values), statistics.stdev(values)
        print(f"- {label}: {mean:.1f} +- {sd:.1f}; worst {max(values):.1f}, best {min(values):.1f}: "
              f"worst/best = {max(values) / min(values):.3f}")

    print()
    summary("320x240, 12 clips, D-MSE", [r["dev12"][0] for r in rows])
    summary("320x240, the 8 clips of blender-dev-extra, D-MSE", [r["extra8"][0] for r in rows])
    for s in scales:
        summary(f"1080p --scale {s}, D-MSE", [r["hd"][s][0] for r in rows if s in r["hd"]])
    for label in rows[0]["other"]:
        values = [r["other"][label] for r in rows if r["other"].get(label) is not None]
        if len(values) >= 2:
            better = "lower" if label.endswith("TC") else "higher"
            print(f"- {label} ({better} is better): {statistics.mean(values):.4g} +- {statistics.stdev(values):.2g}")
    with_val = [r for r in rows if r["validation"]]
    if len(with_val) >= 2:
        rho = spearman([r["validation"][0] for r in with_val], [r["dev12"][0] for r in with_val])
        print(f"- rank agreement (Spearman) of the printed 320x240 validation with the 12 clips: {rho:.2f} "
              f"over {len(with_val)} models")
        if all("auto" in r["hd"] for r in with_val):
            rho = spearman([r["validation"][1] for r in with_val], [r["hd"]["auto"][0] for r in with_val])
            print(f"- rank agreement of the printed 1080p validation with the 1080p clips (--scale auto): {rho:.2f}")
    with_real = [r for r in rows if r["real_validation"] is not None]
    if len(with_real) >= 2:
        print("- printed validation on real clips (`--validation-data`, x fill): "
              + ", ".join(f'{r["name"]} {r["real_validation"]:.3f}' for r in with_real))
        for label, key in (("the 12 clips", lambda r: r["dev12"][0]), ("blender-dev-extra's 8 clips", lambda r: r["extra8"][0])):
            rho = spearman([r["real_validation"] for r in with_real], [key(r) for r in with_real])
            print(f"- rank agreement of the printed real-clip validation with {label}: {rho:.2f} over {len(with_real)} models")
        if all("auto" in r["hd"] for r in with_real):
            rho = spearman([r["real_validation"] for r in with_real], [r["hd"]["auto"][0] for r in with_real])
            print(f"- rank agreement of the printed real-clip validation with the 1080p clips (--scale auto): {rho:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
