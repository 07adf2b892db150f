#!/usr/bin/env python3
"""What the best of every model measured here would score if each frame could pick its own model:
per frame, the lowest D-MSE of `ivp` over every scoring under results/recipe-hd/scores (the 1080p
clips at every scale scored), pooled as `ivp eval` pools frames (their mean), beside `fill` and the
oracle. A bound on what choosing among these models can reach, not a method.

Usage: results/recipe-hd/envelope.py [SCORES_DIR]   (default: scores beside this script)
Leaves out the runs that collapsed or predate the foreground guard (names in SKIP).
"""
import glob
import json
import os
import sys

SKIP = ('guard-s3', 'old-')
here = os.path.dirname(os.path.abspath(__file__))
root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, 'scores')
for label, pattern in [('320x240, 12 clips', 'dev12.json'), ('1080p, 3 clips', 'hd_scale-*.json')]:
    best, fill, oracle, scorings = {}, {}, {}, 0
    for path in sorted(glob.glob(os.path.join(root, '*', pattern))):
        if any(s in path for s in SKIP):
            continue
        scores = json.load(open(path))
        if 'ivp' not in scores['methods']:
            continue
        scorings += 1
        for frame in scores['per_frame']:
            key, d_mse = (frame['clip'], frame['target']), frame['d_mse']
            if d_mse['ivp'] is None:
                continue
            fill[key] = d_mse['fill']
            oracle[key] = d_mse.get('oracle', oracle.get(key))
            if key not in best or d_mse['ivp'] < best[key][0]:
                best[key] = (d_mse['ivp'], os.path.basename(os.path.dirname(path)))
    frames = sorted(best)
    mean = lambda values: sum(values[k] for k in frames) / len(frames)
    best_mse = {k: v[0] for k, v in best.items()}
    print(f'{label}: {scorings} scorings, {len(frames)} frames with disocclusions; fill {mean(fill):.1f}, '
          f'oracle {mean(oracle):.1f} ({mean(oracle) / mean(fill):.3f}x), best model per frame '
          f'{mean(best_mse):.1f} ({mean(best_mse) / mean(fill):.3f}x fill)')
    if len(frames) <= 9:
        for k in frames:
            print(f'  {k[0]} t{k[1]}: fill {fill[k]:.0f}, oracle {oracle[k]:.0f}, best {best[k][0]:.0f} '
                  f'({best[k][0] / fill[k]:.2f}x, {best[k][1]})')
