#!/usr/bin/env python3
"""How much fine detail frames carry: over every rgb/NNNN.png of the given frame number under
each folder, the mean absolute difference of horizontally adjacent pixels (grey levels, 0-255)
and the share of such differences above 20, with the spread over frames.

Usage: results/recipe-hd/texture_detail.py [--frame 6] DIR ...
Needs numpy and Pillow.
"""
import argparse
import glob

import numpy as np
from PIL import Image

parser = argparse.ArgumentParser()
parser.add_argument('--frame', type=int, default=6)
parser.add_argument('dirs', nargs='+')
args = parser.parse_args()
for folder in args.dirs:
    gradients, edges = [], []
    for path in sorted(glob.glob(f'{folder}/**/rgb/{args.frame:04d}.png', recursive=True)):
        grey = np.asarray(Image.open(path).convert('L'), dtype=np.float32)
        step = np.abs(np.diff(grey, axis=1))
        gradients.append(step.mean())
        edges.append((step > 20).mean())
    if not gradients:
        print(f'{folder}: no frame {args.frame}')
        continue
    print(f'{folder}: {len(gradients)} frames; mean |horizontal step| {np.mean(gradients):.2f} '
          f'(sd {np.std(gradients):.2f}), steps above 20: {100 * np.mean(edges):.1f}%')
