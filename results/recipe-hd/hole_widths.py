#!/usr/bin/env python3
"""How wide the holes around the disocclusions are: for every disocclusion pixel, the length of the
horizontal run of hole pixels (disocclusion or new region, ALGORITHMS.md §4.1) that holds it.
Percentiles are over disocclusion pixels, so a wide band counts as much as its area.

Usage: ivp warp --data DATA --export-targets [--targets ...] --out OUT
       results/recipe-hd/hole_widths.py OUT [OUT/CLIP ...]
Reads every *_holes.png under each folder given (255 disocclusion, 128 new region). Needs numpy
and Pillow.
"""
import glob
import sys

import numpy as np
from PIL import Image

for folder in sys.argv[1:]:
    widths, frames = [], 0
    for path in sorted(glob.glob(f'{folder}/**/*_holes.png', recursive=True)):
        holes = np.array(Image.open(path))
        disocclusion, hole = holes == 255, holes > 0
        frames += 1
        for y in np.unique(np.nonzero(disocclusion)[0]):
            xs = np.nonzero(hole[y])[0]
            for run in np.split(xs, np.nonzero(np.diff(xs) > 1)[0] + 1):
                widths += [len(run)] * int(disocclusion[y, run].sum())
    if not widths:
        print(f'{folder}: {frames} frames, no disocclusion pixels')
        continue
    p = np.percentile(widths, [10, 25, 50, 75, 90, 99])
    print(f'{folder}: {frames} frames, {len(widths) // frames} disocclusion pixels a frame; '
          f'run width in px, percentiles 10/25/50/75/90/99: ' + ' / '.join(f'{v:.0f}' for v in p))
