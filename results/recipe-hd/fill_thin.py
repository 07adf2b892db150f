#!/usr/bin/env python3
"""`fill` with the thin-run rule (ALGORITHMS.md §6.5) in front of it, and with the far blur after
it: classical baselines for the network.

Usage: fill_thin.py OUT_DIR...
Each OUT_DIR is written by `ivp infer --clip CLIP --target T --model MODEL --out OUT_DIR
--network-inputs` (any model: only the inputs are read). A disocclusion pixel in a run of at most
3 unknown pixels between two known pixels of its row copies the one of the two with the larger
warped depth (ties left), else the same along its column (ties up), else takes `fill`; then the
far blur as ivp's default (strength 0.5). Prints the D-MSE (0..255) of `fill`, of `fill` with the
rule and of both with the blur, each averaged over the frames with disocclusions, as `ivp eval`
pools them (each prediction rounded to 8 bits). Needs numpy and safetensors; the rule and the blur
are `thin_run_sources` and `blur_far_pixels` of examples/onnx/run_onnx.py.
"""
import os
import sys

import numpy as np
from safetensors.numpy import load_file

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "examples", "onnx"))
from run_onnx import blur_far_pixels, thin_run_sources  # noqa: E402  (as the ONNX example implements them)


def main(out_dirs):
    fill_total = rule_total = blur_total = frames = 0
    for out_dir in out_dirs:
        inputs = load_file(f"{out_dir}/network_inputs.safetensors")
        hole = inputs["hole"][0, 0] > 0.5
        if not hole.any():
            continue
        known = inputs["known"][0, 0] > 0.5
        warped, truth = inputs["warped"][0] * 255, inputs["truth"][0] * 255
        fill = np.round(inputs["fill"][0] * 255)
        ys, xs = np.nonzero(hole)
        prediction = fill.copy()
        thin_ys, thin_xs, source_ys, source_xs = thin_run_sources(known, inputs["depth"][0, 0], hole)
        prediction[:, thin_ys, thin_xs] = warped[:, source_ys, source_xs]
        blurred = np.round(blur_far_pixels(prediction / 255, hole, known) * 255)
        target = truth[:, ys, xs]
        fill_total += ((fill[:, ys, xs] - target) ** 2).mean()
        rule_total += ((prediction[:, ys, xs] - target) ** 2).mean()
        blur_total += ((blurred[:, ys, xs] - target) ** 2).mean()
        frames += 1
    print(f"{frames} frames with disocclusions: fill {fill_total / frames:.1f}, "
          f"fill with thin runs {rule_total / frames:.1f}, and the far blur {blur_total / frames:.1f}")


if __name__ == "__main__":
    main(sys.argv[1:])
