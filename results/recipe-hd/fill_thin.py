#!/usr/bin/env python3
"""`fill` with the thin-run rule (ALGORITHMS.md §6.5) in front of it: a classical baseline for the network.

Usage: fill_thin.py OUT_DIR...
Each OUT_DIR is written by `ivp infer --clip CLIP --target T --model MODEL --out OUT_DIR
--network-inputs` (any model: only the inputs are read). A disocclusion pixel in a run of at most
3 unknown pixels between two known pixels of its row copies the one of the two with the larger
warped depth (ties left), else the same along its column (ties up), else takes `fill`. Prints the
D-MSE (0..255) of `fill` and of `fill` with the rule, each averaged over the frames with
disocclusions, as `ivp eval` pools them. Needs numpy and safetensors.
"""
import sys

import numpy as np
from safetensors.numpy import load_file

THIN_RUN = 3


def thin_sources(known, hole_ys, hole_xs, axis):
    """For each hole pixel, the two known pixels around its run along `axis` (1: row, 0: column)
    and the run's length; (-1, -1) where the run reaches the frame's edge."""
    lines = known if axis == 1 else known.T
    pos = hole_xs if axis == 1 else hole_ys
    line_of = hole_ys if axis == 1 else hole_xs
    before = np.full(len(pos), -1)
    after = np.full(len(pos), -1)
    for i, (line, p) in enumerate(zip(line_of, pos)):
        row = lines[line]
        left = np.nonzero(row[:p])[0]
        right = np.nonzero(row[p + 1:])[0]
        if len(left) and len(right):
            before[i], after[i] = left[-1], p + 1 + right[0]
    return before, after


def main(out_dirs):
    fill_total = rule_total = frames = 0
    for out_dir in out_dirs:
        inputs = load_file(f"{out_dir}/network_inputs.safetensors")
        hole = inputs["hole"][0, 0] > 0.5
        if not hole.any():
            continue
        known = inputs["known"][0, 0] > 0.5
        warped, truth = inputs["warped"][0] * 255, inputs["truth"][0] * 255
        depth = np.nan_to_num(inputs["depth"][0, 0], nan=-np.inf, posinf=-np.inf)
        depth[depth <= 0] = -np.inf  # no valid depth loses to any valid one
        fill = np.round(inputs["fill"][0] * 255)
        ys, xs = np.nonzero(hole)
        prediction = fill[:, ys, xs].copy()
        done = np.zeros(len(ys), bool)
        for axis in (1, 0):
            a, b = thin_sources(known, ys, xs, axis)
            thin = (a >= 0) & (b - a - 1 <= THIN_RUN) & ~done
            if axis == 1:
                ay, ax, by, bx = ys, a, ys, b
            else:
                ay, ax, by, bx = a, xs, b, xs
            ay, ax, by, bx = (np.where(thin, v, 0) for v in (ay, ax, by, bx))
            farther_is_b = depth[by, bx] > depth[ay, ax]
            colour = np.where(farther_is_b, warped[:, by, bx], warped[:, ay, ax])
            prediction[:, thin] = colour[:, thin]
            done |= thin
        target = truth[:, ys, xs]
        fill_total += ((fill[:, ys, xs] - target) ** 2).mean()
        rule_total += ((prediction - target) ** 2).mean()
        frames += 1
    print(f"{frames} frames with disocclusions: fill {fill_total / frames:.1f}, "
          f"fill with thin runs {rule_total / frames:.1f}")


if __name__ == "__main__":
    main(sys.argv[1:])
