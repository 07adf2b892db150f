#!/usr/bin/env python3
"""Which of the four nearest known pixels the disocclusions of a frame should copy.

Usage: directions.py OUT_DIR...
Each OUT_DIR is written by `ivp infer --clip CLIP --target T --model MODEL --out OUT_DIR
--network-inputs` (network_inputs.safetensors, infilled.png). For every disocclusion pixel the
nearest known pixel is found in each direction (left, right, up, down) along its row or column;
prints, over the frame's disocclusions, the D-MSE (0..255) of copying each of them, of `fill`
(the farthest of them), of the network's infilled.png, and of the best of the four by the ground
truth, with how often each direction is that best and how often `fill` picks it; then the D-MSE of
copying the pixel 2 to 48 px beyond the nearest known one to the right (where it is known). The best-by-truth
figure is a bound no predictor reaches: the least of four errors is low by chance too.
Needs numpy, safetensors and Pillow.
"""
import os
import sys

import numpy as np
from PIL import Image
from safetensors.numpy import load_file

DIRECTIONS = {"left": (0, -1), "right": (0, 1), "up": (-1, 0), "down": (1, 0)}


def nearest_known(known, ys, xs, dy, dx):
    """Position of the nearest known pixel from each (y, x) along (dy, dx); -1 where none."""
    h, w = known.shape
    found = np.full((len(ys), 2), -1)
    for i, (y, x) in enumerate(zip(ys, xs)):
        y, x = y + dy, x + dx
        while 0 <= y < h and 0 <= x < w:
            if known[y, x]:
                found[i] = (y, x)
                break
            y, x = y + dy, x + dx
    return found


def main(out_dir):
    inputs = load_file(os.path.join(out_dir, "network_inputs.safetensors"))
    hole = inputs["hole"][0, 0] > 0.5
    known = inputs["known"][0, 0] > 0.5
    warped, truth, depth = inputs["warped"][0] * 255, inputs["truth"][0] * 255, inputs["depth"][0, 0]
    fill = np.round(inputs["fill"][0] * 255)
    network = np.asarray(Image.open(os.path.join(out_dir, "infilled.png")).convert("RGB"), np.float64)
    ys, xs = np.nonzero(hole)
    target = truth[:, ys, xs]

    def d_mse(pred):
        return float(((pred - target) ** 2).mean())

    errors, depths = [], []
    for dy, dx in DIRECTIONS.values():
        at = nearest_known(known, ys, xs, dy, dx)
        ok = at[:, 0] >= 0
        colour = np.where(ok, warped[:, at[:, 0], at[:, 1]], np.nan)
        errors.append(np.where(ok, ((colour - target) ** 2).mean(0), np.inf))
        depths.append(np.where(ok, depth[at[:, 0], at[:, 1]], -np.inf))
    errors, depths = np.stack(errors), np.stack(depths)
    best = errors.argmin(0)
    line = [f"{out_dir}: {len(ys)} disocclusion pixels", f"fill {d_mse(fill[:, ys, xs]):.1f}",
            f"network {d_mse(network.transpose(2, 0, 1)[:, ys, xs]):.1f}"]
    for i, name in enumerate(DIRECTIONS):
        finite = np.isfinite(errors[i])
        line.append(f"{name} {errors[i][finite].mean():.1f} (best for {np.mean(best == i):.2f}, "
                    f"fill's for {np.mean(depths.argmax(0) == i):.2f})")
    line.append(f"best of four by truth {errors.min(0).mean():.1f}")
    # Further along the row than the nearest known pixel to the right, where that pixel is known.
    right = nearest_known(known, ys, xs, 0, 1)
    for beyond in (2, 8, 16, 32, 48):
        y, x = right[:, 0], right[:, 1] + beyond
        ok = (right[:, 0] >= 0) & (x < known.shape[1])
        ok[ok] &= known[y[ok], x[ok]]
        err = ((warped[:, y[ok], x[ok]] - target[:, ok]) ** 2).mean()
        line.append(f"right +{beyond} px {err:.1f} ({ok.mean():.2f} of the pixels)")
    print("; ".join(line))


for d in sys.argv[1:]:
    main(d)
