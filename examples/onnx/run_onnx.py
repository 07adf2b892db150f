"""Runs ivp's exported ONNX graph with onnxruntime and scores it as `ivp eval --iterations 1` does.

    python3 examples/onnx/run_onnx.py MODEL.onnx INPUTS.safetensors [INPUTS.safetensors ...]

Each INPUTS file is what `ivp infer --network-inputs` writes for one target (MODEL.md, "Running
the graph"): the graph's inputs `prior`, `depth`, `hole`, and `warped`, `known`, `fill`, `threshold`, `truth`.
The graph gives the vectors; everything around it is here, in numpy, as ivp does it with one
iteration (ALGORITHMS.md §6.3, §6.5):

- before the graph runs, the thin runs: a disocclusion pixel in a run of at most 3 unknown pixels
  between two known pixels of its row (else of its column) copies the one of the two with the
  larger valid depth (ties: the left or upper one); it becomes known, at that depth, with the
  vector to it as its prior, and leaves the graph's `hole` input;
- each remaining disocclusion pixel p reads the warped frame at p + v, bilinearly over the known corners
  only (the weights renormalised over them);
- a vector that reads nothing is walked along its direction, magnitudes 1..100, and the first
  magnitude that reads a known pixel is taken;
- a pixel that even the walk cannot fill takes the `fill` rule's value, and so does one whose read
  depth is less than its background depth threshold divided by 4 (it read the foreground);
- the far blur (ALGORITHMS.md §6.5): each disocclusion pixel takes the mean of the infilled pixels
  around it, over a window of 0.5 pixels per pixel of distance to the nearest known pixel along its
  row or column, read from a pyramid of the infilled pixels;
- the frame is quantised to 8 bits, and D-MSE is the mean squared error on 0..255 over the
  disocclusion pixels and the three channels; a clip's D-MSE is the mean over its targets.

Needs numpy, onnxruntime and safetensors (pip install numpy onnxruntime safetensors).
"""

import sys

import numpy as np
from safetensors.numpy import load_file

MAX_WALK_MAGNITUDE = 100
FOREGROUND_DEPTH_RATIO = 4.0
THIN_RUN = 3
FAR_BLUR = 0.5
BLUR_LEVELS = 6
BINOMIAL = np.array([1, 4, 6, 4, 1], np.float32) / 16


def thin_run_sources(known, depth, hole, max_run=THIN_RUN):
    """The disocclusion pixels in thin runs and the pixels they copy: arrays ys, xs, source_ys,
    source_xs. Along the row first, then the column, as ivp's `thin_run_source`."""
    valid = np.isfinite(depth) & (depth > 0)
    key = np.where(valid, depth, -np.inf)
    found = []
    for y, x in zip(*np.nonzero(hole)):
        for line, p, along_row in ((known[y], x, True), (known[:, x], y, False)):
            before, after = np.nonzero(line[:p])[0], np.nonzero(line[p + 1:])[0]
            if not len(before) or not len(after):
                continue
            a, b = before[-1], p + 1 + after[0]
            if b - a - 1 > max_run:
                continue
            ends = ((y, a), (y, b)) if along_row else ((a, x), (b, x))
            source = ends[1] if key[ends[1]] > key[ends[0]] else ends[0]
            found.append((y, x) + source)
            break
    rows = np.array(found, np.int64).reshape(-1, 4)
    return rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]


def fill_thin_runs(t):
    """Applies the thin runs to the inputs of one target (in place): the frame and the graph's
    inputs change; returns the frame."""
    hole, known = t["hole"][0, 0] > 0, t["known"][0, 0] > 0
    depth, frame = t["depth"][0, 0], t["warped"][0].copy()
    ys, xs, sy, sx = thin_run_sources(known, depth, hole)
    frame[:, ys, xs] = t["warped"][0][:, sy, sx]
    depth[ys, xs] = depth[sy, sx]
    t["prior"][0, 0, ys, xs] = (sx - xs).astype(np.float32)
    t["prior"][0, 1, ys, xs] = (sy - ys).astype(np.float32)
    t["hole"][0, 0, ys, xs] = 0
    t["known"][0, 0, ys, xs] = 1
    return frame


def known_read(image, known, x, y):
    """Colour (C, N) read at float positions (x, y) over the known corners only, and whether any
    corner was known (N,)."""
    channels, height, width = image.shape
    finite = np.isfinite(x) & np.isfinite(y)
    x, y = np.where(finite, x, 0).astype(np.float32), np.where(finite, y, 0).astype(np.float32)
    x0, y0 = np.floor(x), np.floor(y)
    ax, ay = x - x0, y - y0
    total = np.zeros(x.shape, np.float32)
    colour = np.zeros((channels,) + x.shape, np.float32)
    for dx, dy, weight in ((0, 0, (1 - ax) * (1 - ay)), (1, 0, ax * (1 - ay)), (0, 1, (1 - ax) * ay), (1, 1, ax * ay)):
        cx, cy = x0 + dx, y0 + dy
        inside = finite & (weight > 0) & (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
        ix, iy = np.where(inside, cx, 0).astype(np.int64), np.where(inside, cy, 0).astype(np.int64)
        weight = np.where(inside & known[iy, ix], weight, 0).astype(np.float32)
        total += weight
        colour += weight * image[:, iy, ix]
    found = total > 0
    return colour / np.where(found, total, 1), found


def infill_once(vectors, image, depth, known, fill, threshold, hole):
    """The predicted frame (3, H, W) from one set of vectors (2, H, W): `image` (the warped frame,
    thin runs filled) with the pixels of `hole` read from its `known` pixels."""
    frame = image.copy()
    # Colour and depth are read together: channel 3 is the depth.
    warped = np.concatenate([image, depth[None]])
    read_depth = np.full(hole.shape, np.nan, np.float32)
    ys, xs = np.nonzero(hole)
    # Positions in f32, as ivp adds them.
    fx, fy = xs.astype(np.float32), ys.astype(np.float32)
    a, b = vectors[0, ys, xs], vectors[1, ys, xs]
    colour, found = known_read(warped, known, fx + a, fy + b)
    frame[:, ys[found], xs[found]] = colour[:3, found]
    read_depth[ys[found], xs[found]] = colour[3, found]
    # Walk the vectors that read nothing along their direction.
    todo = ~found
    length = np.hypot(a.astype(np.float64), b.astype(np.float64))
    walkable = todo & np.isfinite(length) & (length > 0)
    da, db = np.where(walkable, a / np.where(walkable, length, 1), 0), np.where(walkable, b / np.where(walkable, length, 1), 0)
    for m in range(1, MAX_WALK_MAGNITUDE + 1):
        if not walkable.any():
            break
        idx = np.nonzero(walkable)[0]
        wx, wy = (m * da[idx]).astype(np.float32), (m * db[idx]).astype(np.float32)
        colour, found = known_read(warped, known, fx[idx] + wx, fy[idx] + wy)
        done = idx[found]
        frame[:, ys[done], xs[done]] = colour[:3, found]
        read_depth[ys[done], xs[done]] = colour[3, found]
        walkable[done] = False
        todo[done] = False
    # What even the walk could not fill, or what read far in front of its background, takes the
    # `fill` rule's value.
    t = threshold[ys, xs]
    todo |= (t > 0) & (read_depth[ys, xs] * np.float32(FOREGROUND_DEPTH_RATIO) < t)
    frame[:, ys[todo], xs[todo]] = fill[:, ys[todo], xs[todo]]
    return frame


def distance_to_known(known):
    """Per pixel, the distance to the nearest known pixel along its row or column (inf if none)."""

    def along_rows(k):
        x = np.arange(k.shape[1])[None, :]
        before = np.maximum.accumulate(np.where(k, x, -(10**9)), axis=1)
        after = np.minimum.accumulate(np.where(k, x, 10**9)[:, ::-1], axis=1)[:, ::-1]
        return np.minimum(x - before, after - x).astype(np.float64)

    d = np.minimum(along_rows(known), along_rows(known.T).T)
    return np.where(d > 10**8, np.inf, d)


def smooth(level):
    """The binomial kernel along both axes, edges repeated (level: H, W, C)."""
    for axis in (1, 0):
        pad = [(0, 0)] * level.ndim
        pad[axis] = (2, 2)
        padded = np.pad(level, pad, mode="edge")
        n = level.shape[axis]
        level = sum(k * np.take(padded, np.arange(t, t + n), axis=axis) for t, k in enumerate(BINOMIAL))
    return level


def pool(level):
    """2x2 cells averaged, the last row or column repeated at odd sizes."""
    h, w = level.shape[:2]
    level = np.pad(level, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    return 0.25 * (level[0::2, 0::2] + level[1::2, 0::2] + level[0::2, 1::2] + level[1::2, 1::2])


def read_level(level, j, ys, xs):
    """Bilinear reads of level j at full-size pixels (ys, xs), positions clamped to the level."""
    h, w = level.shape[:2]
    x = np.clip((xs + 0.5) / 2**j - 0.5, 0, w - 1)
    y = np.clip((ys + 0.5) / 2**j - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    return ((1 - fx) * (1 - fy) * level[y0, x0] + fx * (1 - fy) * level[y0, x1]
            + (1 - fx) * fy * level[y1, x0] + fx * fy * level[y1, x1])


def blur_far_pixels(frame, hole, known, strength=FAR_BLUR):
    """ivp's far blur of the disocclusion pixels `hole` of `frame` (3, H, W), from one another."""
    ys, xs = np.nonzero(hole)
    if len(ys) == 0 or strength <= 0:
        return frame
    window = strength * distance_to_known(known)[ys, xs]
    # Colour times weight, and weight: the infilled pixels weigh 1, every other pixel 0.
    level = np.concatenate([frame.transpose(1, 2, 0), np.ones(hole.shape + (1,), frame.dtype)], axis=2)
    level = (level * hole[..., None]).astype(np.float64)
    own = frame[:, ys, xs].T
    means = []
    for j in range(BLUR_LEVELS):
        if j > 0:
            level = pool(level)
        read = read_level(smooth(level), j, ys, xs)
        weight = read[:, 3:]
        means.append(np.where(weight > 1e-9, read[:, :3] / np.maximum(weight, 1e-30), own))
    means = np.stack(means)
    t = np.clip(window, 0, 1)[:, None]
    out = (1 - t) * own + t * means[0]
    deep = window >= 1
    lv = np.minimum(np.log2(np.maximum(window, 1)), BLUR_LEVELS - 1)
    lo = np.floor(lv).astype(int)
    hi, f = np.minimum(lo + 1, BLUR_LEVELS - 1), (lv - lo)[:, None]
    index = np.arange(len(ys))
    out = np.where(deep[:, None], (1 - f) * means[lo, index] + f * means[hi, index], out)
    frame = frame.copy()
    frame[:, ys, xs] = out.T.astype(frame.dtype)
    return frame


def d_mse(frame, truth, hole):
    quantised = np.round(np.clip(frame, 0, 1) * 255) / 255
    diff = (quantised.astype(np.float64) - truth.astype(np.float64)) * 255
    mask = hole.astype(bool)
    return float((diff[:, mask] ** 2).sum() / (3 * mask.sum())) if mask.any() else None


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    import onnxruntime as ort

    session = ort.InferenceSession(sys.argv[1], providers=["CPUExecutionProvider"])
    scores = []
    for path in sys.argv[2:]:
        t = load_file(path)
        hole, known = t["hole"][0, 0] > 0, t["known"][0, 0] > 0
        frame = fill_thin_runs(t)
        left = t["hole"][0, 0] > 0
        if left.any():
            (vectors,) = session.run(["vectors"], {name: t[name] for name in ("prior", "depth", "hole")})
            now_known = t["known"][0, 0] > 0
            frame = infill_once(vectors[0], frame, t["depth"][0, 0], now_known, t["fill"][0], t["threshold"][0, 0], left)
        frame = blur_far_pixels(frame, hole, known)
        score = d_mse(frame, t["truth"][0], hole)
        print(f"{path}: {hole.sum()} disocclusion pixels, D-MSE {score if score is None else round(score, 2)}")
        if score is not None:
            scores.append(score)
    if scores:
        print(f"mean D-MSE over {len(scores)} targets: {np.mean(scores):.2f}")


if __name__ == "__main__":
    main()
