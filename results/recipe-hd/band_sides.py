#!/usr/bin/env python3
"""What borders each horizontal run of disocclusion pixels of one target: a known pixel or a hole
of the new-region kind (ALGORITHMS.md §4.1), on its left and on its right.

Usage: ivp infer --clip CLIP --target T --model MODEL --out OUT --network-inputs
       results/recipe-hd/band_sides.py OUT/network_inputs.safetensors
Prints the fraction of the disocclusion pixels whose run ends in a new-region pixel on the
right, on the left, and on either side. Needs numpy and safetensors.
"""
import sys

import numpy as np
from safetensors.numpy import load_file

d = load_file(sys.argv[1])
hole = d['hole'][0, 0] > 0.5
known = d['known'][0, 0] > 0.5
height, width = hole.shape
right = left = either = 0
for y in np.unique(np.nonzero(hole)[0]):
    xs = np.nonzero(hole[y])[0]
    for run in np.split(xs, np.nonzero(np.diff(xs) > 1)[0] + 1):
        a, b = run[0], run[-1]
        left_new = not (a > 0 and known[y, a - 1])
        right_new = not (b < width - 1 and known[y, b + 1])
        right += len(run) * right_new
        left += len(run) * left_new
        either += len(run) * (left_new or right_new)
n = hole.sum()
if n == 0:
    sys.exit(f'{sys.argv[1]}: no disocclusion pixels')
print(f'{sys.argv[1]}: {n} disocclusion pixels; their run borders a new region on the right '
      f'{right / n:.2f}, on the left {left / n:.2f}, on either side {either / n:.2f}')
