//! Fictitious infilling vectors and the smoothed temporal prior (ALGORITHMS.md §6.2), and the per-pixel
//! background depth threshold of the iterative infilling (ALGORITHMS.md §6.5).
//!
//! Layer: imports `geometry` only. [`target_prior`] is the one recipe of a target's prior, used by
//! training samples (ivp-data) and by inference alike.

use std::borrow::Cow;
use std::collections::HashMap;

use glam::DMat4;
use rayon::prelude::*;

use crate::geometry::image::is_valid_depth;
use crate::geometry::nearest::NearestKnown;
use crate::geometry::shrink::{blocks_with, shrink_depth, shrink_image_at, shrink_intrinsics};
use crate::geometry::{
    relative_pose, splat_field, warp_forward, warp_known, within_reach, DepthMap, Direction, FrameView, HoleMask,
    Image, Intrinsics, Pixel, RgbImage, VectorField, Warp, WorldToCamera,
};

/// Half the side of the patches compared by the fictitious-vector search (5x5 patches).
pub const PATCH_RADIUS: usize = 2;
/// The fictitious-vector search reads the ground truth only this close to a hole (Chebyshev
/// distance): a candidate is at most 2 pixels from the hole it is found from (one past the
/// nearest known pixel), and patches reach [`PATCH_RADIUS`] further.
pub const GROUND_TRUTH_REACH: usize = PATCH_RADIUS + 2;
/// A candidate is accepted only if its patch RMSE, on the 0..255 scale, is at most this.
pub const MAX_PATCH_RMSE: f32 = 50.0;
/// Half the side of the window over which splatted vectors are averaged (11x11).
pub const PRIOR_WINDOW_RADIUS: usize = 5;
/// Fictitious vectors are measured over two frames (`n-2 -> n`), the prior is for one (`n -> n+1`).
pub const PRIOR_FRAME_GAP: f32 = 2.0;
/// Known pixels per direction that the background depth threshold looks at.
pub const THRESHOLD_PIXELS_PER_DIRECTION: usize = 5;
/// At most this many of the smallest and of the largest depths are averaged into the threshold.
pub const THRESHOLD_MAX_EXTREMES: usize = 5;

// ---------------------------------------------------------------------------------------------
// The prior as the iterative infilling keeps it
// ---------------------------------------------------------------------------------------------

/// A temporal prior at the scale it was measured on (ALGORITHMS.md §6.7), as the iterative
/// infilling keeps it: `coarse` was measured on the frame shrunk by `factor` (1: the frame
/// itself), and the prior reads as a full-size field in which every pixel takes `factor` times its
/// block's vector (vectors are in pixels), except the pixels [`ScaledPrior::set`] since (the
/// infilling sets each pixel it fills to the vector that filled it).
///
/// Why not a full-size field: the network reads the prior at the coarse scale again, so a 1080p
/// frame grew its prior to 2 million pixels only to shrink it back tile by tile (~4 ms of 100).
#[derive(Clone, Debug, PartialEq)]
pub struct ScaledPrior {
    coarse: VectorField,
    factor: usize,
    width: usize,
    height: usize,
    /// Full-size pixels set since, by row-major index (at factor 1 they are set in `coarse`).
    set: HashMap<usize, [f32; 2]>,
}

impl ScaledPrior {
    /// A prior measured on the frame itself.
    pub fn full_size(field: VectorField) -> Self {
        let (width, height) = (field.width(), field.height());
        Self { coarse: field, factor: 1, width, height, set: HashMap::new() }
    }

    /// A prior measured on a `width x height` frame shrunk by `factor`: `coarse` has its size
    /// divided by `factor`, rounded up (the last blocks partial).
    pub fn scaled(coarse: VectorField, factor: usize, width: usize, height: usize) -> Self {
        assert!(factor >= 1, "a scale factor is at least 1");
        assert!(
            coarse.width() == width.div_ceil(factor) && coarse.height() == height.div_ceil(factor),
            "a {}x{} prior is not a {width}x{height} frame shrunk by {factor}",
            coarse.width(),
            coarse.height()
        );
        Self { coarse, factor, width, height, set: HashMap::new() }
    }

    /// No prior (zeros) for a `width x height` frame, kept at `factor`.
    pub fn zeros(width: usize, height: usize, factor: usize) -> Self {
        Self::scaled(VectorField::zeros(width.div_ceil(factor), height.div_ceil(factor)), factor, width, height)
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn factor(&self) -> usize {
        self.factor
    }

    /// The prior as measured, one vector per block (in pixels of the shrunk frame); at factor 1
    /// the full-size field, with the pixels set since.
    pub fn coarse(&self) -> &VectorField {
        &self.coarse
    }

    /// The row-major indices of the full-size pixels set since, in no particular order (none at
    /// factor 1, where they are part of [`ScaledPrior::coarse`]).
    pub fn set_pixels(&self) -> impl Iterator<Item = usize> + '_ {
        self.set.keys().copied()
    }

    /// The full-size vector of pixel `(u, v)`.
    pub fn at(&self, u: usize, v: usize) -> [f32; 2] {
        let s = self.factor;
        match self.set.get(&(v * self.width + u)) {
            Some(&vector) => vector,
            None => self.coarse.get(u / s, v / s).map(|x| x * s as f32),
        }
    }

    /// Sets the full-size pixel of row-major index `i` to `vector`.
    pub fn set(&mut self, i: usize, vector: [f32; 2]) {
        assert!(i < self.width * self.height, "pixel {i} outside the {}x{} prior", self.width, self.height);
        if self.factor == 1 {
            self.coarse.pixels_mut()[i] = vector;
        } else {
            self.set.insert(i, vector);
        }
    }

    /// The prior as a full-size field.
    pub fn to_full(&self) -> VectorField {
        if self.factor == 1 {
            return self.coarse.clone();
        }
        let w = self.width;
        let mut pixels = vec![[0f32; 2]; w * self.height];
        pixels.par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
            for (u, pixel) in row.iter_mut().enumerate() {
                *pixel = self.at(u, v);
            }
        });
        VectorField::from_pixels(w, self.height, pixels)
    }
}

// ---------------------------------------------------------------------------------------------
// Fictitious vectors (ALGORITHMS.md §6.2 step 2)
// ---------------------------------------------------------------------------------------------

/// Fictitious infilling vectors of every hole pixel (every pixel not `known`), measured on the
/// ground truth `ground_truth` of the warped frame. See [`estimate_fictitious_vectors_on`].
pub fn estimate_fictitious_vectors(known: &[bool], ground_truth: &RgbImage) -> VectorField {
    let holes: Vec<bool> = known.iter().map(|&k| !k).collect();
    estimate_fictitious_vectors_on(known, &holes, ground_truth)
}

/// Fictitious infilling vectors of the hole pixels marked in `targets` (ALGORITHMS.md §6.2 step 2).
///
/// For a target hole pixel `p`, each direction (left, right, up, down) proposes a candidate: walk
/// to the nearest known pixel, then one pixel further. Reading of "a direction counts only if it
/// has at least 2 known pixels along it": that nearest known pixel and the next pixel after it are
/// both known and inside the frame; the candidate is the second one. The candidate's 5x5 patch
/// must also lie inside the frame (2 px from the border), as must the patch of `p` (pixels within
/// 2 px of the border get no vector). The 5x5x3 patches of `ground_truth` around `p` and around
/// each candidate are compared by RMSE on the 0..255 scale; the vector points from `p` to the best
/// candidate if its RMSE is at most [`MAX_PATCH_RMSE`], else it is `(0, 0)`. Ties go to the first
/// of left, right, up, down. Known pixels and non-targets get `(0, 0)`.
pub fn estimate_fictitious_vectors_on(known: &[bool], targets: &[bool], ground_truth: &RgbImage) -> VectorField {
    let (w, h) = (ground_truth.width(), ground_truth.height());
    assert_eq!(known.len(), w * h, "known mask does not match the ground truth");
    assert_eq!(targets.len(), w * h, "target mask does not match the ground truth");
    let nearest = NearestKnown::new(w, h, known);
    let mut vectors = vec![[0f32; 2]; w * h];
    vectors.par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
        for (u, out) in row.iter_mut().enumerate() {
            let i = v * w + u;
            if targets[i] && !known[i] {
                *out = fictitious_vector(&nearest, known, ground_truth, (u, v));
            }
        }
    });
    Image::from_pixels(w, h, vectors)
}

/// True when the 5x5 patch around `p` lies inside the frame.
#[inline]
fn patch_fits(p: Pixel, width: usize, height: usize) -> bool {
    p.0 >= PATCH_RADIUS && p.0 + PATCH_RADIUS < width && p.1 >= PATCH_RADIUS && p.1 + PATCH_RADIUS < height
}

/// The second known pixel along `dir` from hole pixel `p` (see [`estimate_fictitious_vectors_on`]).
fn candidate_along(nearest: &NearestKnown, known: &[bool], p: Pixel, dir: Direction) -> Option<Pixel> {
    let (w, h) = (nearest.width(), nearest.height());
    let first = nearest.beyond(p, dir)?;
    let second = dir.step(first, w, h)?;
    (known[second.1 * w + second.0] && patch_fits(second, w, h)).then_some(second)
}

fn fictitious_vector(nearest: &NearestKnown, known: &[bool], ground_truth: &RgbImage, p: Pixel) -> [f32; 2] {
    if !patch_fits(p, ground_truth.width(), ground_truth.height()) {
        return [0.0, 0.0];
    }
    // Compare squared errors: RMSE <= 50 is MSE <= 2500, and the order is the same.
    let max_mse = MAX_PATCH_RMSE * MAX_PATCH_RMSE;
    let mut best: Option<(Pixel, f32)> = None;
    for dir in Direction::ALL {
        let Some(candidate) = candidate_along(nearest, known, p, dir) else { continue };
        let mse = patch_mse_255(ground_truth, p, candidate);
        // A NaN error (NaN in the image) fails both comparisons: such a candidate never wins.
        if mse <= max_mse && best.is_none_or(|(_, best_mse)| mse < best_mse) {
            best = Some((candidate, mse));
        }
    }
    best.map_or([0.0, 0.0], |((cu, cv), _)| [cu as f32 - p.0 as f32, cv as f32 - p.1 as f32])
}

/// Mean squared difference of the 5x5x3 patches of `image` around `a` and `b`, on the 0..255
/// scale. Both patches must fit in the frame.
fn patch_mse_255(image: &RgbImage, a: Pixel, b: Pixel) -> f32 {
    let side = 2 * PATCH_RADIUS + 1;
    let mut sum = 0f32;
    for dv in 0..side {
        let row_a = &image.row(a.1 + dv - PATCH_RADIUS)[a.0 - PATCH_RADIUS..a.0 + PATCH_RADIUS + 1];
        let row_b = &image.row(b.1 + dv - PATCH_RADIUS)[b.0 - PATCH_RADIUS..b.0 + PATCH_RADIUS + 1];
        for (pa, pb) in row_a.iter().zip(row_b) {
            for (x, y) in pa.iter().zip(pb) {
                let d = x - y;
                sum += d * d;
            }
        }
    }
    sum * (255.0 * 255.0) / (side * side * 3) as f32
}

// ---------------------------------------------------------------------------------------------
// Temporal prior (ALGORITHMS.md §6.2 step 3)
// ---------------------------------------------------------------------------------------------

/// The temporal prior `(alpha^w, beta^w)` of the target frame: the fictitious vectors of frame
/// `n` splatted into the target view with `depth_n` and `transform_n_to_t`, each replaced by the
/// mean of the non-zero vectors in its 11x11 window, zeroed where `known_t` (the known mask of
/// the warp `n -> t`) is false, and halved (they span two frames, the prior one).
pub fn temporal_prior(
    vectors_n: &VectorField,
    depth_n: &DepthMap,
    k: &Intrinsics,
    transform_n_to_t: &DMat4,
    known_t: &[bool],
) -> VectorField {
    assert_eq!(known_t.len(), vectors_n.len(), "known mask does not match the vectors");
    let (splatted, _) = splat_field(vectors_n, depth_n, k, transform_n_to_t);
    let mut prior = mean_of_nonzero_vectors(&splatted, PRIOR_WINDOW_RADIUS);
    for (vector, &known) in prior.pixels_mut().iter_mut().zip(known_t) {
        *vector = if known { vector.map(|x| x / PRIOR_FRAME_GAP) } else { [0.0, 0.0] };
    }
    prior
}

/// Every pixel replaced by the mean of the non-zero vectors (either component non-zero) in the
/// `(2 radius + 1)^2` window around it, clipped at the frame border; `(0, 0)` when it has none.
pub fn mean_of_nonzero_vectors(field: &VectorField, radius: usize) -> VectorField {
    let (w, h) = (field.width(), field.height());
    let sums = NonZeroSums::new(field);
    let mut out = vec![[0f32; 2]; w * h];
    out.par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
        let (top, bottom) = (v.saturating_sub(radius), (v + radius + 1).min(h));
        for (u, mean) in row.iter_mut().enumerate() {
            let (left, right) = (u.saturating_sub(radius), (u + radius + 1).min(w));
            let [a, b, count] = sums.over(left..right, top..bottom);
            // Counts are exact integers in f64, so "none" is exactly 0.
            if count > 0.0 {
                *mean = [(a / count) as f32, (b / count) as f32];
            }
        }
    });
    Image::from_pixels(w, h, out)
}

/// Summed-area table of `(a, b, number of non-zero vectors)`, in f64 so that window sums taken as
/// differences of large totals stay accurate on 1080p frames.
struct NonZeroSums {
    /// `width + 1`: entry `(u, v)` sums the pixels of columns `< u` and rows `< v`.
    stride: usize,
    table: Vec<[f64; 3]>,
}

impl NonZeroSums {
    fn new(field: &VectorField) -> Self {
        let (w, h) = (field.width(), field.height());
        let stride = w + 1;
        let mut table = vec![[0f64; 3]; stride * (h + 1)];
        // Pass 1, rows in parallel: prefix sums along each row.
        table.par_chunks_mut(stride).skip(1).zip(field.pixels().par_chunks(w.max(1))).for_each(|(out, row)| {
            let mut row_sum = [0f64; 3];
            for (cell, &[a, b]) in out[1..].iter_mut().zip(row) {
                if a != 0.0 || b != 0.0 {
                    row_sum = [row_sum[0] + a as f64, row_sum[1] + b as f64, row_sum[2] + 1.0];
                }
                *cell = row_sum;
            }
        });
        // Pass 2: accumulate down the columns (each row adds the finished row above it).
        for v in 1..h {
            let (above, below) = table.split_at_mut((v + 1) * stride);
            let above = &above[v * stride..];
            for (cell, up) in below[..stride].iter_mut().zip(above) {
                *cell = [cell[0] + up[0], cell[1] + up[1], cell[2] + up[2]];
            }
        }
        Self { stride, table }
    }

    /// Sums over the columns `cols` and rows `rows` (half-open ranges).
    #[inline]
    fn over(&self, cols: std::ops::Range<usize>, rows: std::ops::Range<usize>) -> [f64; 3] {
        let at = |u: usize, v: usize| self.table[v * self.stride + u];
        let (a, b, c, d) =
            (at(cols.start, rows.start), at(cols.end, rows.start), at(cols.start, rows.end), at(cols.end, rows.end));
        std::array::from_fn(|i| d[i] - b[i] - c[i] + a[i])
    }
}

/// The temporal prior of a target, with the warp of frame `n - 2` into view `n` that it was
/// measured on (the intensity variant reads that warp too, so nobody warps it twice).
#[derive(Clone, Debug)]
pub struct TargetPrior {
    /// `(alpha^w, beta^w)` of the target, zero on its holes.
    pub prior: VectorField,
    /// `f_{n-2}` warped into view `n`: the fictitious vectors were measured on its holes.
    pub warp_to_last: Warp,
}

/// Frame `n - 2` warped into the view of frame `n` (ALGORITHMS.md §6.2 step 1).
pub fn warp_to_last(before_last: &FrameView<'_>, last: &FrameView<'_>, k: &Intrinsics) -> Warp {
    warp_forward(before_last.image, before_last.depth, k, &relative_pose(before_last.pose, last.pose))
}

/// The temporal prior of target `t` from the two last rendered frames (ALGORITHMS.md §6.2 steps 1-3), the
/// one recipe of training samples and inference: warps `n-2` to `n`, measures fictitious vectors
/// on the holes of that warp with `f_n` as ground truth, and turns them into the prior with
/// [`temporal_prior`]. `known_t` is the known mask of the warp `n -> t`.
pub fn target_prior(
    before_last: &FrameView<'_>,
    last: &FrameView<'_>,
    target_pose: &WorldToCamera,
    k: &Intrinsics,
    known_t: &[bool],
) -> TargetPrior {
    let warp_to_last = warp_to_last(before_last, last, k);
    let prior = prior_from_last(&warp_to_last.holes.known(), last, target_pose, k, known_t);
    TargetPrior { prior, warp_to_last }
}

/// [`target_prior`] from the known mask `known_n` of the warp `n - 2 -> n` (steps 2-3): what the
/// prior needs of that warp is where it lands ([`crate::geometry::warp_known`]), not its colours.
/// `last.image` is read only within [`GROUND_TRUTH_REACH`] of the holes of `known_n`.
pub fn prior_from_last(
    known_n: &[bool],
    last: &FrameView<'_>,
    target_pose: &WorldToCamera,
    k: &Intrinsics,
    known_t: &[bool],
) -> VectorField {
    let vectors = estimate_fictitious_vectors(known_n, last.image);
    temporal_prior(&vectors, last.depth, k, &relative_pose(last.pose, target_pose), known_t)
}

/// [`target_prior`] computed on the frames shrunk by `factor`, kept at that scale: as a full-size
/// field, each pixel takes `factor` times the prior of its block, and blocks with a hole take 0.
/// `holes` are those of the warp `n -> t`. At factor 1 it is [`target_prior`]'s prior. This is
/// the form the model reads at inference (`inference::ModelInfiller`).
///
/// Why: the prior's warps and searches cost as much as the rest of a 1080p frame together, while
/// the network that reads it sees the frame shrunk anyway (by the same factor or, by default
/// at 1080p, by half of it: `inference::PriorScale`); measured on the shrunk frames, the prior
/// also looks like the ones the network was trained with (frames of a few hundred rows).
/// Only what the prior reads is shrunk: the depths of frames `n - 2` and `n` (warped whole), and
/// the colours of frame `n` near the holes of the warp `n - 2 -> n` (the fictitious vectors'
/// patches, [`GROUND_TRUTH_REACH`]); frame `n - 2`'s colours are not read at all.
pub fn scaled_target_prior(
    before_last: &FrameView<'_>,
    last: &FrameView<'_>,
    target_pose: &WorldToCamera,
    intrinsics: &Intrinsics,
    holes: &HoleMask,
    factor: usize,
) -> ScaledPrior {
    let s = factor.max(1);
    let (w, h) = (holes.width(), holes.height());
    let known = holes.known();
    let (depth_b, depth_n) = match s {
        1 => (Cow::Borrowed(before_last.depth), Cow::Borrowed(last.depth)),
        _ => {
            let (b, n) = rayon::join(|| shrink_depth(before_last.depth, s), || shrink_depth(last.depth, s));
            (Cow::Owned(b), Cow::Owned(n))
        }
    };
    let k = shrink_intrinsics(intrinsics, s);
    let known_n = warp_known(&depth_b, &k, &relative_pose(before_last.pose, last.pose));
    let image_n = match s {
        1 => Cow::Borrowed(last.image),
        _ => {
            let holes_n: Vec<bool> = known_n.iter().map(|&k| !k).collect();
            let read = within_reach(&holes_n, depth_n.width(), depth_n.height(), GROUND_TRUTH_REACH);
            Cow::Owned(shrink_image_at(last.image, s, Some(&read)))
        }
    };
    let view_n = FrameView { image: &image_n, depth: &depth_n, pose: last.pose };
    if s == 1 {
        return ScaledPrior::full_size(prior_from_last(&known_n, &view_n, target_pose, &k, &known));
    }
    // A block is known when all its pixels are (as in NetworkFrame, where any hole makes a hole).
    let coarse_known: Vec<bool> = blocks_with(w, h, s, &known, false).into_iter().map(|hole| !hole).collect();
    let coarse = prior_from_last(&known_n, &view_n, target_pose, &k, &coarse_known);
    ScaledPrior::scaled(coarse, s, w, h)
}

// ---------------------------------------------------------------------------------------------
// Background depth threshold (ALGORITHMS.md §6.5)
// ---------------------------------------------------------------------------------------------

/// The per-pixel depth threshold of the iterative infilling: a vector of hole pixel `p` is kept
/// when the depth it reads is at least the threshold (it points to background).
///
/// Candidates: in each of the four directions, the (up to) 5 nearest known pixels along the ray,
/// skipping hole pixels in between; known pixels without a valid depth are not candidates. With
/// more than 4 candidates, `k = min(5, count / 4)` and the threshold is the mean of the `k`
/// smallest depths plus the mean of the `k` largest, halved; otherwise `None` (keep every vector).
/// Known pixels get `None`.
pub fn background_depth_threshold(known: &[bool], depth: &DepthMap) -> Vec<Option<f32>> {
    let (w, h) = (depth.width(), depth.height());
    assert_eq!(known.len(), w * h, "known mask does not match the depth map");
    let holes: Vec<usize> = (0..w * h).filter(|&i| !known[i]).collect();
    let mut thresholds = vec![None; w * h];
    for (i, t) in holes.iter().zip(background_depth_thresholds_at(&NearestKnown::new(w, h, known), depth, &holes)) {
        thresholds[*i] = t;
    }
    thresholds
}

/// [`background_depth_threshold`] of the pixels `at` only (row-major indices, none of them known),
/// in their order, with the [`NearestKnown`] of the known mask already built: a frame's holes are
/// a small part of it, and its other pixels would only be skipped.
///
/// The pixels of a run of unknown pixels along a row meet the same known pixels left and right
/// of them, and those of a run along a column the same above and below: the walk from the first
/// known pixel beyond is made once and reused by the next pixels that start from it (within a
/// chunk of `at`; the chunks only share the work out). With the integer sort of
/// [`threshold_from_depths`], the `background_depth_threshold` bench at 1080p takes 26% less
/// time (median of four alternated runs each: 18.1 -> 13.4 ms).
pub fn background_depth_thresholds_at(nearest: &NearestKnown, depth: &DepthMap, at: &[usize]) -> Vec<Option<f32>> {
    let w = depth.width();
    assert!(nearest.width() == w && nearest.height() == depth.height(), "nearest-known size differs from the depth");
    // Few chunks, each with a walk per column and direction to reuse.
    let chunk = at.len().div_ceil(4 * rayon::current_num_threads()).max(256);
    let per_chunk: Vec<Vec<Option<f32>>> = at
        .par_chunks(chunk)
        .map(|pixels| {
            let mut walks = Walks::new(w);
            pixels.iter().map(|&i| walks.threshold_at(nearest, depth, (i % w, i / w))).collect()
        })
        .collect();
    per_chunk.concat()
}

/// The valid depths met walking from a known pixel along a direction, up to
/// [`THRESHOLD_PIXELS_PER_DIRECTION`] of them.
#[derive(Clone, Copy)]
struct Walk {
    from: Option<Pixel>,
    count: usize,
    depths: [f32; THRESHOLD_PIXELS_PER_DIRECTION],
}

impl Walk {
    const NONE: Walk = Walk { from: None, count: 0, depths: [0.0; THRESHOLD_PIXELS_PER_DIRECTION] };

    /// The walk from `from` (itself included) towards `dir`, skipping unknown pixels and pixels
    /// without a valid depth.
    fn from(nearest: &NearestKnown, depth: &DepthMap, from: Pixel, dir: Direction) -> Walk {
        let mut walk = Walk { from: Some(from), ..Walk::NONE };
        let mut next = Some(from);
        while walk.count < THRESHOLD_PIXELS_PER_DIRECTION {
            let Some(q) = next else { break };
            let z = depth.at(q.0, q.1);
            if is_valid_depth(z) {
                walk.depths[walk.count] = z;
                walk.count += 1;
            }
            next = nearest.beyond(q, dir);
        }
        walk
    }

    fn depths(&self) -> &[f32] {
        &self.depths[..self.count]
    }
}

/// The walks last made, to reuse: left and right (the pixel before in a row-major scan starts
/// from the same known pixels when it is in the same run), and up and down per column.
struct Walks {
    left: Walk,
    right: Walk,
    up: Vec<Walk>,
    down: Vec<Walk>,
}

impl Walks {
    fn new(width: usize) -> Self {
        Self { left: Walk::NONE, right: Walk::NONE, up: vec![Walk::NONE; width], down: vec![Walk::NONE; width] }
    }

    fn threshold_at(&mut self, nearest: &NearestKnown, depth: &DepthMap, p: Pixel) -> Option<f32> {
        let mut depths = [0f32; 4 * THRESHOLD_PIXELS_PER_DIRECTION];
        let mut count = 0;
        for dir in Direction::ALL {
            let kept = match dir {
                Direction::Left => &mut self.left,
                Direction::Right => &mut self.right,
                Direction::Up => &mut self.up[p.0],
                Direction::Down => &mut self.down[p.0],
            };
            let first = nearest.beyond(p, dir);
            let walk = match first {
                None => &Walk::NONE,
                Some(q) => {
                    if kept.from != first {
                        *kept = Walk::from(nearest, depth, q, dir);
                    }
                    &*kept
                }
            };
            depths[count..count + walk.count].copy_from_slice(walk.depths());
            count += walk.count;
        }
        threshold_from_depths(&depths[..count])
    }
}

/// `(mean of the k smallest + mean of the k largest) / 2` with `k = min(5, count / 4)`, for more
/// than 4 depths; `None` otherwise. The depths are valid (finite and positive), so their bits
/// order as their values do, and integers sort faster than floats by `total_cmp` (on a 1080p
/// Blender frame, the sort by `total_cmp` was about a third of the thresholds' time).
fn threshold_from_depths(depths: &[f32]) -> Option<f32> {
    if depths.len() <= 4 {
        return None;
    }
    debug_assert!(depths.iter().all(|&z| is_valid_depth(z)), "a threshold of invalid depths");
    let mut bits = [0u32; 4 * THRESHOLD_PIXELS_PER_DIRECTION];
    let bits = &mut bits[..depths.len()];
    bits.iter_mut().zip(depths).for_each(|(b, z)| *b = z.to_bits());
    bits.sort_unstable();
    let k = (bits.len() / 4).min(THRESHOLD_MAX_EXTREMES);
    let mean = |values: &[u32]| values.iter().map(|&b| f32::from_bits(b)).sum::<f32>() / values.len() as f32;
    Some((mean(&bits[..k]) + mean(&bits[bits.len() - k..])) / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene;

    /// The known mask of a `w` x `h` frame whose holes are where `is_hole` says.
    fn known_where_not(w: usize, h: usize, is_hole: impl Fn(usize, usize) -> bool) -> Vec<bool> {
        (0..h).flat_map(|v| (0..w).map(move |u| (u, v))).map(|(u, v)| !is_hole(u, v)).collect()
    }

    fn gray(g: f32) -> [f32; 3] {
        [g, g, g]
    }

    /// Stripes that change along rows only: any horizontal shift of a patch matches exactly.
    fn row_stripes(v: usize) -> [f32; 3] {
        let g = ((v * v * 7 + 3 * v) % 11) as f32 / 10.0;
        [g, 1.0 - g, 0.5]
    }

    fn assert_all_finite(field: &VectorField) {
        assert!(field.as_flat().iter().all(|x| x.is_finite()), "non-finite vector");
    }

    #[test]
    fn a_scaled_prior_reads_as_its_blocks_times_the_factor_except_where_set() {
        let (w, h) = (23usize, 14usize);
        for s in [1, 2, 3, 4, 5] {
            let coarse =
                VectorField::from_fn(w.div_ceil(s), h.div_ceil(s), |u, v| [u as f32 + 0.5, -(v as f32) * 0.25]);
            let mut prior = ScaledPrior::scaled(coarse.clone(), s, w, h);
            prior.set(3 * w + 4, [7.0, -7.0]);
            let full = prior.to_full();
            assert_eq!((full.width(), full.height()), (w, h));
            for (i, &vector) in full.pixels().iter().enumerate() {
                let (u, v) = (i % w, i / w);
                let [x, y] = coarse.get(u / s, v / s);
                let expected = if i == 3 * w + 4 { [7.0, -7.0] } else { [x * s as f32, y * s as f32] };
                assert_eq!((vector, prior.at(u, v)), (expected, expected), "factor {s}, pixel {i}");
            }
            assert_eq!(prior.set_pixels().count(), usize::from(s > 1));
        }
        assert_eq!(ScaledPrior::zeros(5, 3, 2).to_full(), VectorField::zeros(5, 3));
    }

    #[test]
    fn fictitious_vector_points_to_the_matching_side_one_past_the_nearest_known_pixel() {
        // Hole columns 8..=12 over every row (so up and down find nothing). The truth continues the
        // right side's row stripes into the hole; the left side is a different texture.
        let (w, h) = (24, 11);
        let known = known_where_not(w, h, |u, _| (8..=12).contains(&u));
        let truth =
            Image::from_fn(
                w,
                h,
                |u, v| if u < 8 { [((u * 5 + v * 3) % 7) as f32 / 6.0, 0.9, 0.0] } else { row_stripes(v) },
            );
        let vectors = estimate_fictitious_vectors(&known, &truth);
        for v in 2..h - 2 {
            // Nearest known pixel on the right is column 13, the candidate column 14.
            for u in 10..=12 {
                assert_eq!(vectors.get(u, v), [14.0 - u as f32, 0.0], "({u}, {v})");
            }
        }
        // Nothing points into the other texture.
        assert!(vectors.pixels().iter().all(|&[a, b]| a >= 0.0 && b == 0.0));
        assert_all_finite(&vectors);
    }

    #[test]
    fn a_match_worse_than_rmse_50_gives_no_vector() {
        // Hole columns 5..=9; the truth inside is brighter by `delta`. From column 7 both
        // candidates (3 and 11) see 4 columns of background and 1 of hole: RMSE = 255 delta sqrt(0.8).
        let (w, h) = (15, 9);
        let known = known_where_not(w, h, |u, _| (5..=9).contains(&u));
        let vector_at_centre = |delta: f32| {
            let truth = Image::from_fn(w, h, |u, _| gray(if (5..=9).contains(&u) { 0.5 + delta } else { 0.5 }));
            estimate_fictitious_vectors(&known, &truth).get(7, 4)
        };
        // RMSE 45.6: accepted; left and right tie exactly, left wins.
        assert_eq!(vector_at_centre(0.20), [-4.0, 0.0]);
        // RMSE 57.0: rejected.
        assert_eq!(vector_at_centre(0.25), [0.0, 0.0]);
    }

    #[test]
    fn ties_go_to_left_then_right_then_up_then_down() {
        let (w, h) = (15, 15);
        let truth = Image::filled(w, h, gray(0.3));
        let single_hole = known_where_not(w, h, |u, v| (u, v) == (7, 7));
        assert_eq!(estimate_fictitious_vectors(&single_hole, &truth).get(7, 7), [-2.0, 0.0]);
        // Left blocked by the border of the candidate patch: right wins over up and down.
        let hole_near_left = known_where_not(w, h, |u, v| (u, v) == (3, 7));
        assert_eq!(estimate_fictitious_vectors(&hole_near_left, &truth).get(3, 7), [2.0, 0.0]);
        // Left and right blocked by holes after their first known pixel: up wins over down.
        let row_blocked = known_where_not(w, h, |u, v| v == 7 && [5, 7, 9].contains(&u));
        assert_eq!(estimate_fictitious_vectors(&row_blocked, &truth).get(7, 7), [0.0, -2.0]);
    }

    #[test]
    fn a_direction_needs_two_known_pixels_in_a_row() {
        // Row 7: hole at 4, known 5, hole 6, HOLE PIXEL 7, known 8, hole 9. Left and right each have
        // one known pixel before the next hole, so only up and down count.
        let (w, h) = (15, 15);
        let truth = Image::filled(w, h, gray(0.6));
        let known = known_where_not(w, h, |u, v| v == 7 && [4, 6, 7, 9].contains(&u));
        assert_eq!(estimate_fictitious_vectors(&known, &truth).get(7, 7), [0.0, -2.0]);
    }

    #[test]
    fn pixels_near_the_border_and_known_pixels_get_no_vector() {
        let (w, h) = (12, 12);
        let truth = Image::filled(w, h, gray(0.5));
        // Holes at column 1 and at row 1, 10 (within 2 px of the border) and one inner hole.
        let known =
            known_where_not(w, h, |u, v| u == 1 || (v == 1 && u == 6) || (v == 10 && u == 6) || (u, v) == (6, 6));
        let vectors = estimate_fictitious_vectors(&known, &truth);
        for v in 0..h {
            for u in 0..w {
                let expected = if (u, v) == (6, 6) { [-2.0, 0.0] } else { [0.0, 0.0] };
                assert_eq!(vectors.get(u, v), expected, "({u}, {v})");
            }
        }
        // Known pixels get none even as targets; a hole that is not a target gets none either.
        let all = vec![true; w * h];
        assert_eq!(estimate_fictitious_vectors_on(&known, &all, &truth), vectors);
        let mut all_but_one = all;
        all_but_one[6 * w + 6] = false;
        let without = estimate_fictitious_vectors_on(&known, &all_but_one, &truth);
        assert!(without.pixels().iter().all(|&p| p == [0.0, 0.0]));
    }

    #[test]
    fn only_targets_get_vectors_and_nan_in_the_truth_never_leaks() {
        let (w, h) = (7, 5);
        let known = known_where_not(w, h, |u, v| v == 2 && u == 3);
        let truth = Image::filled(w, h, gray(0.5));
        let none = vec![false; w * h];
        assert!(estimate_fictitious_vectors_on(&known, &none, &truth).pixels().iter().all(|&p| p == [0.0, 0.0]));
        // 7x5: the only pixel 2 px inside is (2..5, 2); (3, 2) has candidates at 1 and 5: outside.
        assert_eq!(estimate_fictitious_vectors(&known, &truth).get(3, 2), [0.0, 0.0]);
        let (w, h) = (15, 15);
        let known = known_where_not(w, h, |u, v| (u, v) == (7, 7));
        let mut truth = Image::filled(w, h, gray(0.5));
        truth.set(7, 7, [f32::NAN, 0.0, 0.0]);
        let vectors = estimate_fictitious_vectors(&known, &truth);
        assert_eq!(vectors.get(7, 7), [0.0, 0.0]);
        assert_all_finite(&vectors);
    }

    #[test]
    fn all_hole_and_no_hole_frames() {
        let (w, h) = (9, 8);
        let truth = Image::filled(w, h, gray(0.5));
        for known in [vec![false; w * h], vec![true; w * h]] {
            let vectors = estimate_fictitious_vectors(&known, &truth);
            assert!(vectors.pixels().iter().all(|&p| p == [0.0, 0.0]));
        }
        let empty = Image::<3>::zeros(0, 0);
        assert!(estimate_fictitious_vectors(&[], &empty).is_empty());
    }

    /// The window mean written the slow obvious way.
    fn brute_force_mean(field: &VectorField, radius: usize) -> VectorField {
        let (w, h) = (field.width(), field.height());
        Image::from_fn(w, h, |u, v| {
            let (mut sum, mut count) = ([0f64; 2], 0);
            for y in v.saturating_sub(radius)..(v + radius + 1).min(h) {
                for x in u.saturating_sub(radius)..(u + radius + 1).min(w) {
                    let [a, b] = field.get(x, y);
                    if a != 0.0 || b != 0.0 {
                        sum = [sum[0] + a as f64, sum[1] + b as f64];
                        count += 1;
                    }
                }
            }
            if count == 0 {
                [0.0, 0.0]
            } else {
                sum.map(|s| (s / count as f64) as f32)
            }
        })
    }

    #[test]
    fn window_mean_ignores_zero_vectors() {
        let (w, h) = (21, 17);
        let mut field = Image::zeros(w, h);
        field.set(10, 8, [4.0, -2.0]);
        field.set(12, 8, [2.0, 0.0]);
        let mean = mean_of_nonzero_vectors(&field, PRIOR_WINDOW_RADIUS);
        assert_eq!(mean.get(8, 8), [3.0, -1.0]); // both in the window, the zeros not counted
        assert_eq!(mean.get(5, 3), [4.0, -2.0]); // only (10, 8)
        assert_eq!(mean.get(16, 13), [2.0, 0.0]); // only (12, 8)
        assert_eq!(mean.get(4, 8), [0.0, 0.0]); // neither
        assert_eq!(mean.get(10, 14), [0.0, 0.0]);
    }

    #[test]
    fn window_mean_matches_brute_force_on_odd_and_tiny_sizes() {
        for (w, h) in [(7, 5), (1, 1), (23, 3), (40, 31)] {
            let field = Image::from_fn(w, h, |u, v| {
                let s = (u * 31 + v * 17) % 13;
                if s < 6 {
                    [0.0, 0.0]
                } else {
                    [s as f32 - 9.5, if s % 2 == 0 { 0.0 } else { 1.25 * s as f32 }]
                }
            });
            let fast = mean_of_nonzero_vectors(&field, PRIOR_WINDOW_RADIUS);
            let slow = brute_force_mean(&field, PRIOR_WINDOW_RADIUS);
            for (i, (a, b)) in fast.pixels().iter().zip(slow.pixels()).enumerate() {
                assert!((a[0] - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5, "{w}x{h} pixel {i}: {a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn temporal_prior_is_zero_at_target_holes_and_halved_elsewhere() {
        let (w, h) = (30, 20);
        let k = test_scene::intrinsics();
        let depth = Image::filled(w, h, [4.0]);
        let mut vectors = Image::zeros(w, h);
        vectors.set(12, 10, [6.0, 0.0]);
        vectors.set(13, 10, [0.0, -4.0]);
        let known_t = known_where_not(w, h, |u, v| (10..=14).contains(&u) && (8..=11).contains(&v));
        let prior = temporal_prior(&vectors, &depth, &k, &DMat4::IDENTITY, &known_t);
        let smoothed = mean_of_nonzero_vectors(&vectors, PRIOR_WINDOW_RADIUS);
        for v in 0..h {
            for u in 0..w {
                let got = prior.get(u, v);
                let want = if known_t[v * w + u] { smoothed.get(u, v).map(|x| x / 2.0) } else { [0.0, 0.0] };
                assert!(
                    (got[0] - want[0]).abs() < 1e-5 && (got[1] - want[1]).abs() < 1e-5,
                    "({u}, {v}): {got:?} vs {want:?}"
                );
            }
        }
        // Known pixel next to the hole, both vectors in its window: (6 + 0) / 2 / 2, (0 - 4) / 2 / 2.
        let beside = prior.get(15, 10);
        assert!((beside[0] - 1.5).abs() < 1e-5 && (beside[1] + 1.0).abs() < 1e-5, "{beside:?}");
        assert_eq!(prior.get(12, 10), [0.0, 0.0]);
    }

    /// Frames n-2, n and t of the box scene at camera x = 0, 0.2, 0.3, and the known mask of the
    /// warp n -> t.
    fn box_scene() -> (Intrinsics, [(RgbImage, DepthMap, WorldToCamera); 3], Vec<bool>) {
        let k = test_scene::intrinsics();
        let frames = [0.0, 0.2, 0.3].map(test_scene::render);
        let (f2, d2, p2) = &frames[1];
        let known_t = warp_forward(f2, d2, &k, &relative_pose(p2, &frames[2].2)).holes.known();
        (k, frames, known_t)
    }

    #[test]
    fn prior_of_a_box_scene_points_to_the_background_on_known_pixels_only() {
        // Camera moving right: the box moves left and uncovers wall on its right, which matches the
        // wall further right.
        let (k, [(f0, d0, p0), (f2, d2, p2), (_, _, p3)], known_t) = box_scene();
        let before_last = FrameView { image: &f0, depth: &d0, pose: &p0 };
        let last = FrameView { image: &f2, depth: &d2, pose: &p2 };
        let TargetPrior { prior, warp_to_last } = target_prior(&before_last, &last, &p3, &k, &known_t);
        assert_eq!(warp_to_last.image, warp_forward(&f0, &d0, &k, &relative_pose(&p0, &p2)).image);
        assert_all_finite(&prior);
        let nonzero: Vec<[f32; 2]> = prior.pixels().iter().copied().filter(|&[a, b]| a != 0.0 || b != 0.0).collect();
        assert!(nonzero.len() > 20, "only {} non-zero prior vectors", nonzero.len());
        // Fictitious vectors are 2..=7 px to the right, halved: the prior points right, 1..=3.5 px.
        assert!(nonzero.iter().all(|&[a, b]| (1.0 - 1e-4..=3.5 + 1e-4).contains(&a) && b == 0.0), "{nonzero:?}");
        assert!(prior.pixels().iter().zip(&known_t).all(|(p, &known)| known || *p == [0.0, 0.0]));
    }

    #[test]
    fn the_prior_needs_only_the_known_mask_of_the_warp_and_the_last_frame_near_its_holes() {
        let (k, [(f0, d0, p0), (f2, d2, p2), (_, _, p3)], known_t) = box_scene();
        let before_last = FrameView { image: &f0, depth: &d0, pose: &p0 };
        let last = FrameView { image: &f2, depth: &d2, pose: &p2 };
        let whole = target_prior(&before_last, &last, &p3, &k, &known_t).prior;
        let known_n = crate::geometry::warp_known(&d0, &k, &relative_pose(&p0, &p2));
        assert_eq!(known_n, warp_to_last(&before_last, &last, &k).holes.known());
        // The last frame replaced by NaN beyond `reach` of the holes.
        let (w, h) = (f2.width(), f2.height());
        let holes: Vec<bool> = known_n.iter().map(|&k| !k).collect();
        let prior_with_last_cut_at = |reach: usize| {
            let near = crate::geometry::within_reach(&holes, w, h, reach);
            assert!(near.iter().filter(|&&n| !n).count() > w * h / 2, "most of the frame is out of reach");
            let pixels = f2.pixels().iter().zip(&near).map(|(&p, &n)| if n { p } else { [f32::NAN; 3] }).collect();
            let cut = RgbImage::from_pixels(w, h, pixels);
            prior_from_last(&known_n, &FrameView { image: &cut, ..last }, &p3, &k, &known_t)
        };
        assert!(whole.pixels().iter().any(|&v| v != [0.0, 0.0]));
        assert_eq!(prior_with_last_cut_at(GROUND_TRUTH_REACH), whole);
        // One pixel less of reach does change it: the reach is not larger than needed.
        assert_ne!(prior_with_last_cut_at(GROUND_TRUTH_REACH - 1), whole);
    }

    #[test]
    fn threshold_separates_near_and_far() {
        // Near (1) on the left, far (10) on the right; hole columns 9..=10 over every row, so each
        // hole pixel sees 5 + 5 candidates: k = 2, threshold (1 + 10) / 2.
        let (w, h) = (20, 9);
        let depth = Image::from_fn(w, h, |u, _| [if u < 10 { 1.0 } else { 10.0 }]);
        let known = known_where_not(w, h, |u, _| u == 9 || u == 10);
        let thresholds = background_depth_threshold(&known, &depth);
        for v in 0..h {
            for u in 0..w {
                let expected = if known[v * w + u] { None } else { Some(5.5) };
                assert_eq!(thresholds[v * w + u], expected, "({u}, {v})");
            }
        }
    }

    #[test]
    fn threshold_averages_up_to_five_extremes_and_skips_holes_along_a_ray() {
        // Single hole at (10, 10) with another hole at (8, 10); depth = sqrt(u + 100 v) (uneven, so
        // the number of extremes averaged matters). Left: 9, 7, 6, 5, 4; right 11..=15; up rows
        // 9..=5; down rows 11..=15. 20 candidates: k = 5, the 5 up ones are the smallest, the 5
        // down ones the largest.
        let (w, h) = (21, 21);
        let depth_of = |u: usize, v: usize| ((u + 100 * v) as f32).sqrt();
        let depth = Image::from_fn(w, h, |u, v| [depth_of(u, v)]);
        let known = known_where_not(w, h, |u, v| v == 10 && (u == 10 || u == 8));
        let threshold = background_depth_threshold(&known, &depth)[10 * w + 10].unwrap();
        let smallest = (5..=9).map(|v| depth_of(10, v)).sum::<f32>() / 5.0;
        let largest = (11..=15).map(|v| depth_of(10, v)).sum::<f32>() / 5.0;
        let expected = (smallest + largest) / 2.0;
        assert!((threshold - expected).abs() < 1e-4, "{threshold} vs {expected}");
        // Make the left candidates beyond the hole at (8, 10) very far: the 5 largest are now those
        // 4 and the farthest downward one. A ray that stopped at the hole would not see them.
        let mut lopsided = depth.clone();
        for u in 0..8 {
            lopsided.set(u, 10, [1000.0]);
        }
        let threshold = background_depth_threshold(&known, &lopsided)[10 * w + 10].unwrap();
        let largest = (4000.0 + depth_of(10, 15)) / 5.0;
        assert!((threshold - (smallest + largest) / 2.0).abs() < 1e-3, "{threshold}");
    }

    #[test]
    fn threshold_needs_more_than_four_candidates() {
        // 5x5, holes everywhere but the middle of each border (4 candidates for the centre).
        let (w, h) = (5, 5);
        let depth = Image::from_fn(w, h, |u, v| [1.0 + (u + 5 * v) as f32]);
        let mut known = known_where_not(w, h, |u, v| !matches!((u, v), (0, 2) | (4, 2) | (2, 0) | (2, 4)));
        assert_eq!(background_depth_threshold(&known, &depth)[12], None);
        // One more known pixel: 5 candidates, k = 1: (smallest + largest) / 2.
        known[2 * w + 1] = true;
        let depths = [depth.at(0, 2), depth.at(1, 2), depth.at(4, 2), depth.at(2, 0), depth.at(2, 4)];
        let (lo, hi) = (depths.iter().copied().fold(f32::MAX, f32::min), depths.iter().copied().fold(0.0, f32::max));
        assert_eq!(background_depth_threshold(&known, &depth)[12], Some((lo + hi) / 2.0));
    }

    #[test]
    fn thresholds_with_shared_walks_equal_a_walk_per_pixel() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (w, h) in [(1, 1), (9, 1), (1, 9), (37, 23), (300, 40)] {
            // Wide and tall blocks, scattered pixels, and invalid depths among the known pixels.
            let known: Vec<bool> = (0..w * h)
                .map(|i| {
                    let (u, v) = (i % w, i / w);
                    !((u % 17 < 6 && v % 11 < 7) || rng.random_bool(0.1))
                })
                .collect();
            let depths: Vec<[f32; 1]> = (0..w * h)
                .map(|_| {
                    [match rng.random_range(0..10) {
                        0 => f32::NAN,
                        1 => 0.0,
                        2 => f32::INFINITY,
                        _ => rng.random_range(0.1..50.0),
                    }]
                })
                .collect();
            let depth = Image::from_pixels(w, h, depths);
            // Every unknown pixel but some (as new regions are unknown and not asked for).
            let at: Vec<usize> = (0..w * h).filter(|&i| !known[i] && i % 5 != 0).collect();
            let one_step_walks = |i: usize| {
                let mut depths = Vec::new();
                for dir in Direction::ALL {
                    let (mut taken, mut q) = (0, dir.step((i % w, i / w), w, h));
                    while let (Some((u, v)), true) = (q, taken < THRESHOLD_PIXELS_PER_DIRECTION) {
                        let z = depth.at(u, v);
                        if known[v * w + u] && is_valid_depth(z) {
                            depths.push(z);
                            taken += 1;
                        }
                        q = dir.step((u, v), w, h);
                    }
                }
                threshold_from_depths(&depths)
            };
            let want: Vec<Option<u32>> = at.iter().map(|&i| one_step_walks(i).map(f32::to_bits)).collect();
            let nearest = NearestKnown::new(w, h, &known);
            let got: Vec<Option<u32>> = background_depth_thresholds_at(&nearest, &depth, &at)
                .into_iter()
                .map(|t| t.map(f32::to_bits))
                .collect();
            assert_eq!(got, want, "{w}x{h}");
            assert!(want.iter().any(Option::is_some) || w * h < 100, "{w}x{h}: no threshold tested");
        }
    }

    #[test]
    fn threshold_sorts_depths_by_their_bits_as_by_their_values() {
        use rand::{Rng, SeedableRng};
        // The formula over depths sorted as floats, summed in the same order.
        let by_values = |depths: &[f32]| {
            let mut sorted = depths.to_vec();
            sorted.sort_by(f32::total_cmp);
            let k = (sorted.len() / 4).min(THRESHOLD_MAX_EXTREMES);
            let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
            (sorted.len() > 4).then(|| (mean(&sorted[..k]) + mean(&sorted[sorted.len() - k..])) / 2.0)
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for count in 0..=4 * THRESHOLD_PIXELS_PER_DIRECTION {
            for _ in 0..200 {
                // Subnormal to huge depths, and ties.
                let depths: Vec<f32> = (0..count)
                    .map(|_| match rng.random_range(0..4) {
                        0 => f32::from_bits(rng.random_range(1..0x0080_0000)),
                        1 => rng.random_range(1e30..f32::MAX),
                        2 => 2.5,
                        _ => rng.random_range(0.01..100.0),
                    })
                    .collect();
                let (got, want) = (threshold_from_depths(&depths), by_values(&depths));
                assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "{depths:?}");
            }
        }
    }

    #[test]
    fn threshold_ignores_invalid_depths_and_handles_degenerate_frames() {
        let (w, h) = (7, 5);
        let depth = Image::from_fn(w, h, |u, _| [if u % 2 == 0 { f32::NAN } else { 2.0 }]);
        let known = known_where_not(w, h, |u, v| (u, v) == (3, 2));
        let thresholds = background_depth_threshold(&known, &depth);
        // Candidates with a valid depth: left 1, right 5, up (3,1), (3,0), down (3,3), (3,4): all 2.
        assert_eq!(thresholds[2 * w + 3], Some(2.0));
        assert!(thresholds.iter().flatten().all(|t| t.is_finite()));
        assert!(background_depth_threshold(&vec![false; w * h], &depth).iter().all(Option::is_none));
        assert!(background_depth_threshold(&vec![true; w * h], &depth).iter().all(Option::is_none));
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let (w, h) = (41, 37);
        let truth = Image::from_fn(w, h, |u, v| gray(((u * 13 + v * 7) % 23) as f32 / 22.0));
        let known = known_where_not(w, h, |u, v| (u * 3 + v * 5) % 7 == 0 || (10..20).contains(&u));
        let depth = Image::from_fn(w, h, |u, v| [1.0 + ((u + v) % 5) as f32]);
        let run = |n| {
            rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| {
                let vectors = estimate_fictitious_vectors(&known, &truth);
                (mean_of_nonzero_vectors(&vectors, PRIOR_WINDOW_RADIUS), background_depth_threshold(&known, &depth))
            })
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn the_scaled_prior_is_the_training_prior_at_factor_one_and_zero_on_holes() {
        use crate::test_scene::{intrinsics, render};
        let k = intrinsics();
        let frames: Vec<_> = [0.0, 0.2, 0.3].into_iter().map(render).collect();
        let warped = warp_forward(&frames[1].0, &frames[1].1, &k, &relative_pose(&frames[1].2, &frames[2].2));
        let view = |i: usize| FrameView { image: &frames[i].0, depth: &frames[i].1, pose: &frames[i].2 };
        let known = warped.holes.known();
        let scaled = |s: usize| scaled_target_prior(&view(0), &view(1), &frames[2].2, &k, &warped.holes, s).to_full();
        // The training form (samples) and the inference form are one recipe: equal at factor 1.
        let fine = target_prior(&view(0), &view(1), &frames[2].2, &k, &known).prior;
        assert_eq!(scaled(1), fine);
        let shrunk = scaled(2);
        let mean_x = |field: &VectorField| {
            let xs: Vec<f32> = field.pixels().iter().filter(|p| p[0] != 0.0).map(|p| p[0]).collect();
            xs.iter().sum::<f32>() / xs.len().max(1) as f32
        };
        assert!(shrunk.pixels().iter().zip(&known).all(|(p, &k)| k || *p == [0.0, 0.0]));
        // The box slides left in view: both priors point the same way, by about as far.
        let (a, b) = (mean_x(&fine), mean_x(&shrunk));
        assert!(a != 0.0 && b != 0.0 && a.signum() == b.signum(), "fine {a}, shrunk {b}");
        assert!((b / a - 1.0).abs() < 0.5, "fine {a}, shrunk {b}");
        assert!(shrunk.pixels().iter().flatten().all(|x| x.is_finite()));
    }

    #[test]
    fn the_scaled_prior_equals_the_prior_of_the_whole_shrunk_last_frame_across_a_wide_hole() {
        // A wide near block at camera x = 0 uncovers a band of striped wall about 22 px wide by
        // x = 0.25: 11 blocks at factor 2, whose middle is beyond the reach of either side.
        let k = test_scene::intrinsics();
        let (w, h) = (test_scene::WIDTH, test_scene::HEIGHT);
        let on_block = |u: usize, v: usize, camera_x: f64| {
            let x = (u as f64 - k.cx) / k.fx + camera_x;
            (8..40).contains(&v) && (-0.2..0.2).contains(&x)
        };
        let frame = |camera_x: f64| {
            let image =
                Image::from_fn(w, h, |u, v| if on_block(u, v, camera_x) { test_scene::RED } else { row_stripes(v) });
            let depth = Image::from_fn(w, h, |u, v| [if on_block(u, v, camera_x) { 1.0 } else { 10.0 }]);
            (image, depth, WorldToCamera(DMat4::from_translation(glam::DVec3::new(-camera_x, 0.0, 0.0))))
        };
        let [(f0, d0, p0), (f1, d1, p1), (_, _, p2)] = [0.0, 0.25, 0.3].map(frame);
        let (before_last, last) =
            (FrameView { image: &f0, depth: &d0, pose: &p0 }, FrameView { image: &f1, depth: &d1, pose: &p1 });
        let holes = warp_forward(&f1, &d1, &k, &relative_pose(&p1, &p2)).holes;
        let s = 2;
        // The same recipe with the whole last frame shrunk.
        let (depth_n, k_n) = (shrink_depth(&d1, s), shrink_intrinsics(&k, s));
        let known_n = warp_known(&shrink_depth(&d0, s), &k_n, &relative_pose(&p0, &p1));
        let near_known = within_reach(&known_n, depth_n.width(), depth_n.height(), GROUND_TRUTH_REACH);
        assert!(near_known.iter().any(|&near| !near), "no hole block is beyond reach of the known ones");
        let image_n = shrink_image_at(&f1, s, None);
        let coarse_known: Vec<bool> =
            blocks_with(w, h, s, &holes.known(), false).into_iter().map(|hole| !hole).collect();
        let view_n = FrameView { image: &image_n, depth: &depth_n, pose: &p1 };
        let whole =
            ScaledPrior::scaled(prior_from_last(&known_n, &view_n, &p2, &k_n, &coarse_known), s, w, h).to_full();
        let scaled = scaled_target_prior(&before_last, &last, &p2, &k, &holes, s).to_full();
        assert!(whole.pixels().iter().filter(|&&v| v != [0.0, 0.0]).count() > 20);
        let differ = scaled.pixels().iter().zip(whole.pixels()).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{differ} pixels differ from the prior of the whole shrunk frame");
    }
}
