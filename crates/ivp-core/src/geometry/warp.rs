//! Forward warping by depth-weighted bilinear splatting (ALGORITHMS.md §4).
//!
//! Each valid source pixel is lifted to 3-D with its depth, moved by the relative pose, projected
//! into the target view and splatted onto the four integer neighbours of where it lands. The
//! weight of a splat is the bilinear weight times a depth weight that lets the nearest surface win
//! by a factor of up to `e^50`, so the numerics follow ALGORITHMS.md §4 to the letter: projection in f64,
//! coordinates within [`SNAP_PX`] of an integer snapped onto it, bilinear weights below
//! [`MIN_BILINEAR_WEIGHT`] dropped.
//!
//! The depth weights need the largest depth before anything is splatted, so there are two passes.
//! Pass 1 projects every source pixel to find that depth and, for each chunk of `CHUNK` source
//! pixels of a row, the target rows it reaches. Pass 2 cuts the target frame into bands of rows
//! (`band_rows`); each band projects again the chunks that reach it, in source order, and
//! accumulates into a scratch small enough to stay in cache. Every target pixel therefore sums its
//! splats in source order, whatever the number of threads, bands or chunks: the same input gives
//! the same bits on any machine, and the same bits as a plain serial loop over the source pixels.

use std::mem::MaybeUninit;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use glam::DMat4;
use rayon::prelude::*;

use crate::geometry::camera::Intrinsics;
use crate::geometry::holes::HoleMask;
use crate::geometry::image::{DepthMap, Image, RgbImage};

/// A transformed point must be at least this far in front of the camera to be splatted.
pub const MIN_Z: f64 = 1e-6;
/// Depths beyond this are clamped when computing depth weights *(ref)*.
pub const MAX_WEIGHT_DEPTH: f64 = 1000.0;
/// The depth weights of the nearest and farthest surfaces differ by `e^DEPTH_WEIGHT_RANGE`.
pub const DEPTH_WEIGHT_RANGE: f64 = 50.0;
/// Projected coordinates this close to an integer are snapped onto it.
pub const SNAP_PX: f64 = 1e-6;
/// Bilinear weights below this are dropped, so a far surface never loses to a sliver of a near one.
pub const MIN_BILINEAR_WEIGHT: f64 = 1e-3;
/// Source pixels of a row projected together: the unit of the target-row extents of pass 1 and
/// of the vectorised loops. Small, so that a chunk of a row tilted by a roll of the camera
/// reaches few bands.
const CHUNK: usize = 64;
/// Target rows per band of pass 2, at least: few chunks of a frame of head motion reach two bands
/// and are projected twice (7% more), and a band's accumulator (32 bytes a pixel, 2 MB for 1920
/// columns) stays in cache. See [`band_rows`] for more.
const MIN_BAND_ROWS: usize = 32;
/// Bands are made taller (see `band_rows`) while a chunk reaches more bands than this on average
/// and their accumulator fits in [`MAX_BAND_BYTES`].
const MAX_BANDS_PER_CHUNK: f64 = 1.5;
/// The largest accumulator of a band, about a quarter of the L3 cache.
const MAX_BAND_BYTES: usize = 8 << 20;
/// f32 lanes of one accumulator block.
const LANES: usize = 8;
/// Accumulator cells past a band's pixels that take the splats not made, and are never read.
const SINKS: usize = 16;

/// A frame warped into another view.
#[derive(Clone, Debug)]
pub struct Warp {
    /// Warped colours; holes are black.
    pub image: RgbImage,
    /// Warped planar depth in the target camera; holes are 0.
    pub depth: DepthMap,
    pub holes: HoleMask,
}

/// Warps `image` with its planar `depth` by `transform` (source camera to target camera, see
/// [`crate::geometry::relative_pose`]). Source and target share the intrinsics `k` and the image size.
pub fn warp_forward(image: &RgbImage, depth: &DepthMap, k: &Intrinsics, transform: &DMat4) -> Warp {
    assert!(image.same_size(depth), "image and depth differ in size");
    let src = image.pixels();
    let splat = splat(depth, k, transform, None, |i| src[i]);
    let holes = HoleMask::classify(image.width(), image.height(), &splat.known);
    Warp { image: splat.values, depth: splat.depth, holes }
}

/// The known mask of [`warp_forward`] without moving any values: all that the temporal prior
/// needs of the warp `n - 2 -> n`.
///
/// A pixel is known when any splat reaches it: every splat made weighs more than nothing (a
/// bilinear weight of at least [`MIN_BILINEAR_WEIGHT`] times a depth weight of at least
/// `e^-DEPTH_WEIGHT_RANGE`), so no depth weight, largest depth, band or accumulator is needed:
/// the points are placed as [`warp_forward`] places them and their target pixels marked.
pub fn warp_known(depth: &DepthMap, k: &Intrinsics, transform: &DMat4) -> Vec<bool> {
    let (w, h) = (depth.width(), depth.height());
    if w * h == 0 {
        return Vec::new();
    }
    assert!(w < i32::MAX as usize && h < i32::MAX as usize, "a {w}x{h} frame is too large to warp");
    let proj = Projector::new(w, h, k, transform);
    let whole = 0..h;
    // A mark per target pixel, then the sinks of the splats not made. Threads mark pixels of
    // other threads' rows: stores of `true`, in any order, give the same marks.
    let marks: Vec<AtomicBool> = (0..w * h + SINKS).map(|_| AtomicBool::new(false)).collect();
    depth.pixels().par_chunks(w).enumerate().for_each_init(ChunkSplats::new, |splats, (v, row)| {
        for (c, depth) in row.chunks(CHUNK).enumerate() {
            proj.place(v, c * CHUNK, depth, &whole, w * h, splats);
            for targets in &splats.target {
                targets[..depth.len()].iter().for_each(|&t| marks[t as usize].store(true, Ordering::Relaxed));
            }
        }
    });
    marks.into_iter().take(w * h).map(AtomicBool::into_inner).collect()
}

/// Moves any per-pixel field (e.g. infilling vectors) the way [`warp_forward`] moves colours.
/// Returns the warped field (0 in holes) and the known mask of the warp.
pub fn splat_field<const C: usize>(
    field: &Image<C>,
    depth: &DepthMap,
    k: &Intrinsics,
    transform: &DMat4,
) -> (Image<C>, Vec<bool>) {
    assert!(field.same_size(depth), "field and depth differ in size");
    let src = field.pixels();
    let s = splat(depth, k, transform, None, |i| src[i]);
    (s.values, s.known)
}

struct Splatted<const C: usize> {
    values: Image<C>,
    /// The warped planar depth, splatted like the values.
    depth: DepthMap,
    known: Vec<bool>,
}

/// Where one source point goes.
#[derive(Clone, Copy)]
struct Projection {
    /// In front of the camera (see [`Projector::transform`]) and at least one of its four target
    /// pixels is inside the frame.
    lands: bool,
    /// Depth in the target camera.
    z: f64,
    /// Landing coordinates, snapped.
    qx: f64,
    qy: f64,
}

/// The per-source-pixel part of the warp, prepared once per call.
struct Projector {
    k: Intrinsics,
    width: usize,
    height: usize,
    /// The components of `R * [(u - cx) / fx, 0, 0]` for each column, one vector each so that
    /// loops over a chunk vectorise.
    col_terms: [Vec<f64>; 3],
    rotation_y: [f64; 3],
    rotation_z: [f64; 3],
    translation: [f64; 3],
}

impl Projector {
    fn new(width: usize, height: usize, k: &Intrinsics, t: &DMat4) -> Self {
        let (rx, ry, rz) = (t.x_axis, t.y_axis, t.z_axis);
        let a: Vec<f64> = (0..width).map(|u| (u as f64 - k.cx) / k.fx).collect();
        Self {
            k: *k,
            width,
            height,
            col_terms: [rx.x, rx.y, rx.z].map(|r| a.iter().map(|a| r * a).collect()),
            rotation_y: [ry.x, ry.y, ry.z],
            rotation_z: [rz.x, rz.y, rz.z],
            translation: [t.w_axis.x, t.w_axis.y, t.w_axis.z],
        }
    }

    /// `R * [0, (v - cy) / fy, 1]` for row `v`.
    fn row_term(&self, v: usize) -> [f64; 3] {
        let b = (v as f64 - self.k.cy) / self.k.fy;
        std::array::from_fn(|i| self.rotation_y[i] * b + self.rotation_z[i])
    }

    /// The column terms of pixels `u0..u0 + n`.
    fn col_terms(&self, u0: usize, n: usize) -> [&[f64]; 3] {
        [0, 1, 2].map(|i| &self.col_terms[i][u0..u0 + n])
    }

    /// Moves the source pixel with column term `col`, row term `row` and depth `depth` into the
    /// target camera. Also says whether its depth is valid (`is_valid_depth`, on the f64 so that
    /// all masks have the same width) and the moved depth finite and in front of the camera;
    /// the point is then in front if its x and y are finite too ([`in_front`]).
    /// Branch-free (`&` on bools, selects) like the rest, so that the loops calling it vectorise.
    #[inline(always)]
    fn transform(&self, col: [f64; 3], row: &[f64; 3], depth: f32) -> ([f64; 3], bool) {
        let d = depth as f64;
        let x: [f64; 3] = std::array::from_fn(|i| d * (col[i] + row[i]) + self.translation[i]);
        (x, (d > 0.0) & (d < f64::INFINITY) & (x[2] > MIN_Z) & (x[2] < f64::INFINITY))
    }

    /// Projects the source pixel with column term `col`, row term `row` and depth `depth`.
    #[inline(always)]
    fn project(&self, col: [f64; 3], row: &[f64; 3], depth: f32) -> Projection {
        let (x, z_in_front) = self.transform(col, row, depth);
        let inv_z = 1.0 / x[2];
        let qx = snap(self.k.fx * x[0] * inv_z + self.k.cx);
        let qy = snap(self.k.fy * x[1] * inv_z + self.k.cy);
        // False for infinities and NaNs, so with a finite z it implies finite x and y.
        let inside = (qx > -1.0) & (qx < self.width as f64) & (qy > -1.0) & (qy < self.height as f64);
        Projection { lands: z_in_front & inside, z: x[2], qx, qy }
    }

    /// Pass 1 over the pixels `u0..` of row `v` with depths `depth`: the largest clamped depth in
    /// front of the camera and the target rows reached.
    fn survey(&self, v: usize, u0: usize, depth: &[[f32; 1]]) -> Survey {
        let n = depth.len();
        let row = self.row_term(v);
        let [cx, cy, cz] = self.col_terms(u0, n);
        let (height, last_row) = (self.height as f64, (self.height - 1) as f64);
        // Per point first, reduced after: the loop vectorises only without a reduction in it.
        let (mut z, mut first, mut last) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        let (z, first, last) = (&mut z[..n], &mut first[..n], &mut last[..n]);
        for p in 0..n {
            let (x, z_in_front) = self.transform([cx[p], cy[p], cz[p]], &row, depth[p][0]);
            z[p] = select(in_front(&x, z_in_front), min(x[2], MAX_WEIGHT_DEPTH), 0.0);
            // The rows reached, with a margin instead of the snap (which moves a coordinate by
            // less than SNAP_PX) and whatever the column: a little more than `project` finds, for
            // less work. Clamped to the frame, and the first negated so that it is a maximum too.
            let qy = self.k.fy * x[1] * (1.0 / x[2]) + self.k.cy;
            let (low, high) = ((qy - 2.0 * SNAP_PX).floor(), (qy + 2.0 * SNAP_PX).floor());
            let reaches = z_in_front & (high >= -1.0) & (low < height);
            first[p] = select(reaches, -max(low, 0.0), f64::NEG_INFINITY);
            last[p] = select(reaches, min(high + 1.0, last_row), f64::NEG_INFINITY);
        }
        let (first, last) = (-largest(first), largest(last));
        let rows = if first <= last { TargetRows { first: first as i32, last: last as i32 } } else { TargetRows::NONE };
        Survey { z_max: largest(z), rows }
    }

    /// Pass 2, first half: the splats of the pixels `u0..` of row `v` that fall in the target
    /// rows `band`, into `out`, weighed by depth. A target pixel is an index in the band; a splat
    /// that is not made goes to one of the [`SINKS`] cells from `sink` on.
    #[allow(clippy::too_many_arguments)]
    fn weigh(
        &self,
        v: usize,
        u0: usize,
        depth: &[[f32; 1]],
        band: &Range<usize>,
        sink: usize,
        weight_of_depth: &DepthWeight,
        out: &mut ChunkSplats,
    ) {
        self.place(v, u0, depth, band, sink, out);
        let ChunkSplats { weight: [w00, w10, w01, w11], weight_z, .. } = out;
        let n = depth.len();
        let (w00, w10, w01, w11) = (&mut w00[..n], &mut w10[..n], &mut w01[..n], &mut w11[..n]);
        for ((((w00, w10), w01), w11), &z) in w00.iter_mut().zip(w10).zip(w01).zip(w11).zip(&weight_z[..n]) {
            let wd = weight_of_depth.at_clamped(z);
            (*w00, *w10, *w01, *w11) = (*w00 * wd, *w10 * wd, *w01 * wd, *w11 * wd);
        }
    }

    /// [`Projector::weigh`] before the depth weights: the target pixels and bilinear weights of
    /// the splats, the depths in the target camera and the depths the weights are taken of.
    fn place(&self, v: usize, u0: usize, depth: &[[f32; 1]], band: &Range<usize>, sink: usize, out: &mut ChunkSplats) {
        let n = depth.len();
        let row = self.row_term(v);
        let [cx, cy, cz] = self.col_terms(u0, n);
        let (width, last_col) = (self.width as f64, (self.width - 1) as f64);
        let (band_first, band_rows) = (band.start as f64, band.len() as f64);
        let offsets = [0, 1, self.width as i64, self.width as i64 + 1];
        let ChunkSplats { weight: [w00, w10, w01, w11], target: [t00, t10, t01, t11], z, weight_z } = out;
        let (w00, w10, w01, w11) = (&mut w00[..n], &mut w10[..n], &mut w01[..n], &mut w11[..n]);
        let (t00, t10, t01, t11) = (&mut t00[..n], &mut t10[..n], &mut t01[..n], &mut t11[..n]);
        let (z, weight_z) = (&mut z[..n], &mut weight_z[..n]);
        // In f64 like the projection, 4 lanes a vector; the depth weights, in f32, follow in a
        // loop of their own that runs 8 lanes a vector.
        for p in 0..n {
            let q = self.project([cx[p], cy[p], cz[p]], &row, depth[p][0]);
            let (fx0, fy0) = (q.qx.floor(), q.qy.floor());
            let (ax, ay) = (q.qx - fx0, q.qy - fy0);
            let bilinear = [(1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay];
            // Whether the left and right target columns are in the frame and the top and bottom
            // target rows in the band (none of them, for a point that does not land).
            let top_row = fy0 - band_first;
            let in_frame = [q.lands & (fx0 >= 0.0), q.lands & (fx0 < last_col)];
            let in_band = [(top_row >= 0.0) & (top_row < band_rows), (top_row >= -1.0) & (top_row < band_rows - 1.0)];
            let top_left = integer_to_i64(select(q.lands, top_row * width + fx0, 0.0));
            // Sinks in turns, so that the splats not made by neighbouring points do not wait
            // on each other.
            let sink = (sink + p % 4 * 4) as i64;
            let splat = |c: usize| {
                let made = in_frame[c & 1] & in_band[c >> 1] & (bilinear[c] >= MIN_BILINEAR_WEIGHT);
                // The weight of a splat not made is anything, even NaN: only its sink sees it.
                (bilinear[c] as f32, select_i64(made, top_left + offsets[c], sink + c as i64))
            };
            ((w00[p], t00[p]), (w10[p], t10[p]), (w01[p], t01[p]), (w11[p], t11[p])) =
                (splat(0), splat(1), splat(2), splat(3));
            z[p] = q.z as f32;
            // Only landing points reach the fast ln and exp, which assume a depth of at least 0.
            weight_z[p] = select(q.lands, min(q.z, MAX_WEIGHT_DEPTH), 0.0) as f32;
        }
    }
}

/// A moved point `x` counts towards the largest depth when its depth is in front of the camera
/// (`z_in_front`, see [`Projector::transform`]) and its x and y are finite too.
#[inline(always)]
fn in_front(x: &[f64; 3], z_in_front: bool) -> bool {
    z_in_front & (x[0].abs() < f64::INFINITY) & (x[1].abs() < f64::INFINITY)
}

/// `x as i64` for an integer `x` with `|x| < 2^51`: the bits of `x + 1.5 * 2^52` hold it in their
/// low half, offset. A float-to-int cast, which saturates, would keep the loop from vectorising.
#[inline(always)]
fn integer_to_i64(x: f64) -> i64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    (x + MAGIC).to_bits() as i64 - MAGIC.to_bits() as i64
}

/// The largest of `xs` (-inf if none), for numbers. In lanes, so that it vectorises: a float
/// maximum is not associative for the compiler, which keeps a plain fold sequential.
fn largest(xs: &[f64]) -> f64 {
    let mut lanes = [f64::NEG_INFINITY; 4];
    let mut chunks = xs.chunks_exact(lanes.len());
    for chunk in &mut chunks {
        lanes = std::array::from_fn(|l| max(lanes[l], chunk[l]));
    }
    chunks.remainder().iter().chain(&lanes).fold(f64::NEG_INFINITY, |a, &b| max(a, b))
}

/// `if keep { x } else { otherwise }` with bit masks. The compiler turns a plain `if` into
/// branches, and then in vectorised loops into masked stores, which are slow.
#[inline(always)]
fn select(keep: bool, x: f64, otherwise: f64) -> f64 {
    let mask = (keep as u64).wrapping_neg();
    f64::from_bits((x.to_bits() & mask) | (otherwise.to_bits() & !mask))
}

/// [`select`] for i64.
#[inline(always)]
fn select_i64(keep: bool, x: i64, otherwise: i64) -> i64 {
    let mask = -(keep as i64);
    (x & mask) | (otherwise & !mask)
}

/// `a.min(b)` for numbers, without the NaN handling of `f64::min` that keeps loops from vectorising.
#[inline(always)]
fn min(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

/// `a.max(b)` for numbers, without the NaN handling of `f64::max` that keeps loops from vectorising.
#[inline(always)]
fn max(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else {
        b
    }
}

/// What pass 1 finds about a chunk of source pixels.
struct Survey {
    /// The largest `min(z, MAX_WEIGHT_DEPTH)` of the points in front of the camera (0 if none).
    z_max: f64,
    rows: TargetRows,
}

/// The target rows `first..=last` that some source points reach; empty when `first > last`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct TargetRows {
    first: i32,
    last: i32,
}

impl TargetRows {
    const NONE: Self = Self { first: i32::MAX, last: i32::MIN };

    fn union(self, other: Self) -> Self {
        Self { first: self.first.min(other.first), last: self.last.max(other.last) }
    }

    fn meets(self, band: &Range<usize>) -> bool {
        self.first <= self.last && (self.first as usize) < band.end && (self.last as usize) >= band.start
    }
}

/// The splats of one chunk of source pixels into one band, one array per quantity: filled by
/// loops that vectorise, then applied by a scalar one.
struct ChunkSplats {
    /// Weights of the splats to the top-left, top-right, bottom-left and bottom-right target
    /// pixels of each point.
    weight: [[f32; CHUNK]; 4],
    /// Index in the band's accumulator of each splat's target pixel, or of a sink for a splat
    /// not made (dropped, outside the frame or outside the band).
    target: [[i64; CHUNK]; 4],
    /// Depth in the target camera.
    z: [f32; CHUNK],
    /// The depth that enters the depth weight: clamped, 0 for a point that does not land.
    weight_z: [f32; CHUNK],
}

impl ChunkSplats {
    fn new() -> Box<Self> {
        Box::new(Self { weight: [[0.0; CHUNK]; 4], target: [[0; CHUNK]; 4], z: [0.0; CHUNK], weight_z: [0.0; CHUNK] })
    }
}

/// One block of a target pixel's accumulator: lanes `[weight, weight * z, weight * value...]`,
/// padded; a field of more than `LANES - 2` channels takes several blocks per pixel. A splat is
/// then one vector load, multiply-add and store per block, and being aligned a block never
/// straddles cache lines.
#[derive(Clone, Copy, Default)]
#[repr(C, align(32))]
struct Block([f32; LANES]);

/// Accumulator blocks per target pixel of a field of `c` channels.
const fn blocks_per_pixel(c: usize) -> usize {
    (c + 2).div_ceil(LANES)
}

/// Lane `k` of the accumulator of a pixel (over all its blocks), before weighting: `1`, the
/// depth, the value's channels, then padding.
#[inline(always)]
fn lane<const C: usize>(k: usize, z: f32, value: &[f32; C]) -> f32 {
    match k {
        0 => 1.0,
        1 => z,
        _ => value.get(k - 2).copied().unwrap_or(0.0),
    }
}

/// `(1 + z)^(-50 / ln(1 + z_max))`, written so that it never overflows: in `[e^-50, 1]`.
/// It only weighs surfaces against each other, so it is evaluated in f32 with [`ln_at_least_one`]
/// and [`exp_nonpositive`], which are exact to better than 1e-6 and, unlike libm's, cheap and inlined in
/// the hottest loop of the warp.
struct DepthWeight {
    scale: f32,
}

impl DepthWeight {
    fn new(z_max: f64) -> Self {
        Self { scale: (-DEPTH_WEIGHT_RANGE / z_max.min(MAX_WEIGHT_DEPTH).ln_1p()) as f32 }
    }

    #[cfg(test)]
    fn at(&self, z: f64) -> f32 {
        self.at_clamped(z.min(MAX_WEIGHT_DEPTH) as f32)
    }

    /// The weight of depth `z` already clamped to `0..=MAX_WEIGHT_DEPTH`.
    #[inline(always)]
    fn at_clamped(&self, z: f32) -> f32 {
        exp_nonpositive(self.scale * ln_at_least_one(1.0 + z))
    }
}

/// `ln(x)` for finite `x >= 1`, within 3 ulps of the exact value for `x <= 1 + MAX_WEIGHT_DEPTH`.
#[inline]
fn ln_at_least_one(x: f32) -> f32 {
    const SQRT_2: f32 = std::f32::consts::SQRT_2;
    let bits = x.to_bits();
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    // Branch-free, so that a row of weights vectorises: keep m in [sqrt(1/2), sqrt(2)).
    let big = m > SQRT_2;
    let m = if big { m * 0.5 } else { m };
    let e = ((bits >> 23) & 0xff) as i32 - 127 + big as i32;
    // ln(m) = 2 atanh(s) with |s| <= 0.172: the series converges fast.
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = 1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0))));
    e as f32 * std::f32::consts::LN_2 + 2.0 * s * series
}

/// `exp(y)` for `-87 <= y <= 0`, relative error below 3e-7.
#[inline]
fn exp_nonpositive(y: f32) -> f32 {
    // ln 2 split in two (Cody-Waite) so that `n * LN2_HI` is exact for the n that occur here.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let n = (y * std::f32::consts::LOG2_E).round_ties_even();
    let r = (y - n * LN2_HI) - n * LN2_LO;
    // Taylor series of exp(r) for |r| <= ln(2)/2.
    let p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    // 2^n from the bits of n + 127 written in the mantissa of 2^23 + (n + 127): the same as
    // `(n as i32 + 127) << 23`, but a float-to-int cast would keep the loop from vectorising.
    p * f32::from_bits((n + (8_388_608.0 + 127.0)).to_bits() << 23)
}

/// Snaps `x` onto the nearest integer when within [`SNAP_PX`] of it. Ties (x.5) are never within
/// reach, so rounding them to even is as good as away from zero, and is one instruction.
#[inline(always)]
fn snap(x: f64) -> f64 {
    let r = x.round_ties_even();
    if (x - r).abs() < SNAP_PX {
        r
    } else {
        x
    }
}

/// Splats `value` (of source pixel `i`) and the depth; with bands of `band_rows` target rows if
/// given (for tests), else of [`band_rows`].
fn splat<const C: usize>(
    depth: &DepthMap,
    k: &Intrinsics,
    t: &DMat4,
    band_rows: Option<usize>,
    value: impl Fn(usize) -> [f32; C] + Sync,
) -> Splatted<C> {
    let (w, h) = (depth.width(), depth.height());
    // Not zeroed first: `normalise` writes every pixel of every band, and the bands cover the
    // frame (zeroing 34 MB at 1080p took a millisecond on one thread).
    let (mut values, mut depth_out, mut known) =
        (Vec::<[f32; C]>::with_capacity(w * h), Vec::<f32>::with_capacity(w * h), Vec::<bool>::with_capacity(w * h));
    if w * h > 0 {
        assert!(w < i32::MAX as usize && h < i32::MAX as usize, "a {w}x{h} frame is too large to warp");
        let proj = Projector::new(w, h, k, t);
        let d = depth.pixels();
        let chunks_per_row = w.div_ceil(CHUNK);
        let chunk_pixels = |v: usize, c: usize| v * w + c * CHUNK..v * w + ((c + 1) * CHUNK).min(w);

        // Pass 1: the largest clamped depth in front of the camera, over every point, and the
        // target rows each chunk reaches.
        let mut chunk_rows = vec![TargetRows::NONE; h * chunks_per_row];
        let z_max = chunk_rows
            .par_chunks_mut(chunks_per_row)
            .enumerate()
            .map(|(v, rows)| {
                let mut z_max = 0f64;
                for (c, rows) in rows.iter_mut().enumerate() {
                    let s = proj.survey(v, c * CHUNK, &d[chunk_pixels(v, c)]);
                    (z_max, *rows) = (z_max.max(s.z_max), s.rows);
                }
                z_max
            })
            .reduce(|| 0.0, f64::max);
        let row_rows: Vec<TargetRows> =
            chunk_rows.chunks(chunks_per_row).map(|c| c.iter().fold(TargetRows::NONE, |a, &b| a.union(b))).collect();
        let weight_of_depth = DepthWeight::new(z_max);

        // Pass 2, band by band of target rows. The bands are handed out from a queue to one
        // worker per thread, so that each worker clears and warms one accumulator: a rayon split
        // of its own would take one for every piece of work stolen.
        let band_rows = band_rows.unwrap_or_else(|| self::band_rows(&chunk_rows, w, h, blocks_per_pixel(C)));
        let band_pixels = band_rows * w;
        let bands = (values.spare_capacity_mut()[..w * h].chunks_mut(band_pixels))
            .zip(depth_out.spare_capacity_mut()[..w * h].chunks_mut(band_pixels))
            .zip(known.spare_capacity_mut()[..w * h].chunks_mut(band_pixels));
        let queue = Mutex::new(bands.enumerate());
        let workers = rayon::current_num_threads().min(h.div_ceil(band_rows));
        (0..workers).into_par_iter().for_each(|_| {
            let mut acc = vec![Block::default(); (band_pixels + SINKS) * blocks_per_pixel(C)];
            let mut splats = ChunkSplats::new();
            loop {
                // A statement of its own, so that the lock is released before the work.
                let job = queue.lock().unwrap().next();
                let Some((b, ((values, depth_out), known))) = job else { break };
                let band = b * band_rows..((b + 1) * band_rows).min(h);
                for v in (0..h).filter(|&v| row_rows[v].meets(&band)) {
                    for c in (0..chunks_per_row).filter(|&c| chunk_rows[v * chunks_per_row + c].meets(&band)) {
                        let pixels = chunk_pixels(v, c);
                        proj.weigh(v, c * CHUNK, &d[pixels.clone()], &band, band_pixels, &weight_of_depth, &mut splats);
                        accumulate(&splats, pixels, &mut acc, &value);
                    }
                }
                normalise(&mut acc, values, depth_out, known);
            }
        });
        // SAFETY: the workers took every band from the queue, and `normalise` wrote each of
        // their pixels: all `w h` values of the three are initialised.
        unsafe {
            values.set_len(w * h);
            depth_out.set_len(w * h);
            known.set_len(w * h);
        }
    }
    Splatted { values: Image::from_pixels(w, h, values), depth: Image::from_values(w, h, depth_out), known }
}

/// Target rows per band for a `w` x `h` frame whose chunks reach `chunk_rows`, with `blocks`
/// accumulator blocks a pixel. A chunk that reaches several bands is projected for each: in a
/// frame of large parallax, say near and far pixels mixed and a big step up, a chunk may reach
/// most bands of [`MIN_BAND_ROWS`]. Taller bands then cost less, while they fit the cache.
/// Any band height gives the same result, so this only weighs speed.
fn band_rows(chunk_rows: &[TargetRows], w: usize, h: usize, blocks: usize) -> usize {
    let tallest = MAX_BAND_BYTES / (w * blocks * std::mem::size_of::<Block>());
    let reaching = || chunk_rows.iter().filter(|r| r.first <= r.last);
    let chunks = reaching().count();
    let mut rows = MIN_BAND_ROWS;
    while rows < h && rows * 2 <= tallest {
        let bands_reached: usize = reaching().map(|r| r.last as usize / rows - r.first as usize / rows + 1).sum();
        if bands_reached as f64 <= MAX_BANDS_PER_CHUNK * chunks as f64 {
            break;
        }
        rows *= 2;
    }
    rows
}

/// Pass 2, second half: adds the splats of the source pixels `pixels` to a band's accumulator
/// `acc`, in source order. Without a branch: a splat not made adds to a sink instead.
fn accumulate<const C: usize>(
    splats: &ChunkSplats,
    pixels: Range<usize>,
    acc: &mut [Block],
    value: &impl Fn(usize) -> [f32; C],
) {
    let blocks = const { blocks_per_pixel(C) };
    for (p, i) in pixels.enumerate() {
        let (z, value) = (splats.z[p], value(i));
        for b in 0..blocks {
            let contribution: [f32; LANES] = std::array::from_fn(|l| lane(b * LANES + l, z, &value));
            for c in 0..4 {
                let (wt, target) = (splats.weight[c][p], splats.target[c][p] as usize);
                for (a, x) in acc[target * blocks + b].0.iter_mut().zip(contribution) {
                    *a += wt * x;
                }
            }
        }
    }
}

/// Divides a band's accumulated values and depths by their weights into the outputs (every pixel
/// of the band: 0 and not known where no weight arrived), marks the pixels that received any
/// weight as known, and clears those for the next band (the others are still 0; the sinks are
/// never read).
fn normalise<const C: usize>(
    acc: &mut [Block],
    values: &mut [MaybeUninit<[f32; C]>],
    depth: &mut [MaybeUninit<f32>],
    known: &mut [MaybeUninit<bool>],
) {
    let blocks = const { blocks_per_pixel(C) };
    let get = |cell: &[Block], k: usize| cell[k / LANES].0[k % LANES];
    for (((cell, value), depth), known) in acc.chunks_exact_mut(blocks).zip(values).zip(depth).zip(known) {
        let weight = get(cell, 0);
        if weight > 0.0 {
            let inv = 1.0 / weight;
            value.write(std::array::from_fn(|c| get(cell, c + 2) * inv));
            depth.write(get(cell, 1) * inv);
            known.write(true);
            cell.fill(Block::default());
        } else {
            value.write([0.0; C]);
            depth.write(0.0);
            known.write(false);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::holes::PixelClass;
    use glam::{DMat3, DVec3, DVec4};

    fn k() -> Intrinsics {
        Intrinsics::new(100.0, 100.0, 31.5, 23.5)
    }

    fn textured(w: usize, h: usize) -> RgbImage {
        Image::from_fn(w, h, |u, v| [u as f32 / w as f32, v as f32 / h as f32, ((u * 7 + v * 13) % 17) as f32 / 17.0])
    }

    /// Compares two images within `tol`, reporting the first mismatch (not the whole image).
    fn assert_close<const C: usize>(a: &Image<C>, b: &Image<C>, tol: f32) {
        assert!(a.same_size(b));
        for (i, (p, q)) in a.pixels().iter().zip(b.pixels()).enumerate() {
            let diff = p.iter().zip(q).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
            assert!(diff <= tol, "pixel ({}, {}): {p:?} vs {q:?}", i % a.width(), i / a.width());
        }
    }

    fn translation(x: f64, y: f64, z: f64) -> DMat4 {
        DMat4::from_translation(DVec3::new(x, y, z))
    }

    #[test]
    fn identity_pose_is_the_identity_warp_with_no_holes() {
        let (w, h) = (64, 48);
        let img = textured(w, h);
        // Depth edges everywhere: a checkerboard of near and far surfaces.
        let depth = Image::from_fn(w, h, |u, v| [if (u / 5 + v / 3) % 2 == 0 { 1.0 } else { 40.0 }]);
        let out = warp_forward(&img, &depth, &k(), &DMat4::IDENTITY);
        assert_eq!(out.holes.count(PixelClass::Known), w * h);
        assert_close(&out.image, &img, 1e-6);
        assert_close(&out.depth, &depth, 1e-5);
    }

    #[test]
    fn fronto_parallel_plane_shifts_by_fx_t_over_z() {
        let (w, h) = (64, 48);
        let img = textured(w, h);
        let z = 5.0;
        let depth = Image::filled(w, h, [z as f32]);
        // Camera moves 0.1 right: points move 0.1 left in camera space, by fx * 0.1 / z = 2 px.
        let t = translation(-0.1, 0.0, 0.0);
        let out = warp_forward(&img, &depth, &k(), &t);
        for v in 0..h {
            for u in 0..w {
                if u + 2 < w {
                    let (got, want) = (out.image.get(u, v), img.get(u + 2, v));
                    assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "({u}, {v}): {got:?} vs {want:?}");
                    assert!((out.depth.at(u, v) - z as f32).abs() < 1e-5);
                } else {
                    assert_eq!(out.holes.class(u, v), PixelClass::NewRegion);
                }
            }
        }
    }

    #[test]
    fn a_half_pixel_shift_blends_each_pair_of_neighbours_equally() {
        // A plane at z = 5 moved by 0.025: fx * 0.025 / 5 = 0.5 px to the left.
        let (w, h) = (32, 8);
        let img = textured(w, h);
        let out = warp_forward(&img, &Image::filled(w, h, [5.0]), &k(), &translation(-0.025, 0.0, 0.0));
        for (u, v) in [(3, 2), (10, 5), (20, 7)] {
            let (a, b) = (img.get(u, v), img.get(u + 1, v));
            let want: [f32; 3] = std::array::from_fn(|c| (a[c] + b[c]) / 2.0);
            assert_close(&Image::from_fn(1, 1, |_, _| out.image.get(u, v)), &Image::filled(1, 1, want), 1e-6);
        }
    }

    #[test]
    fn a_landing_within_snap_px_of_a_pixel_is_that_pixel() {
        // Moved by 4e-7 px (less than SNAP_PX), every point lands on its own pixel with the bits of
        // the identity warp; unsnapped, its bilinear weight 1 - 4e-7 would change the last bits.
        let (w, h) = (64, 48);
        let img = textured(w, h);
        let depth = Image::from_fn(w, h, |u, v| [1.0 + ((u * 3 + v * 5) % 11) as f32]);
        let identity = warp_forward(&img, &depth, &k(), &DMat4::IDENTITY);
        // A shift of d px at depth z needs a translation of d z / fx: the same d for every depth
        // only with a rotation, so turn the camera by d / fx radians about its y axis instead.
        let turn = DMat4::from_mat3(DMat3::from_rotation_y(4e-7 / 100.0));
        let turned = warp_forward(&img, &depth, &k(), &turn);
        assert!(turned.image == identity.image && turned.depth == identity.depth);
    }

    #[test]
    fn box_in_front_of_wall_opens_a_disocclusion_on_the_trailing_side() {
        // Wall at z = 10, box at z = 2 over columns 20..30. Camera moves right by 0.2: the box moves
        // left by fx*0.2/2 = 10 px, the wall by 2 px, uncovering 8 px of wall right of the box.
        let (w, h) = (64, 48);
        let depth =
            Image::from_fn(w, h, |u, v| [if (20..30).contains(&u) && (10..38).contains(&v) { 2.0 } else { 10.0 }]);
        let img = textured(w, h);
        let out = warp_forward(&img, &depth, &k(), &translation(-0.2, 0.0, 0.0));
        for v in 12..36 {
            // Box now covers 10..20; wall column c lands at c - 2, so wall columns 30.. land at 28..
            // Pixels 20..28 are uncovered wall behind the box's old position.
            for u in 20..28 {
                assert_eq!(out.holes.class(u, v), PixelClass::Disocclusion, "({u}, {v})");
            }
            assert!(out.holes.is_known(19, v) && out.holes.is_known(28, v));
            assert!((out.depth.at(15, v) - 2.0).abs() < 1e-6);
            let (got, want) = (out.image.get(15, v), img.get(25, v));
            assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6));
        }
        // Nothing opens on the leading side of the box.
        assert!((10..38).all(|v| (0..20).all(|u| out.holes.class(u, v) != PixelClass::Disocclusion)));
    }

    #[test]
    fn points_behind_the_camera_are_dropped() {
        let (w, h) = (16, 12);
        let img = textured(w, h);
        let depth = Image::filled(w, h, [1.0]);
        // Move the camera 2 units forward: every point is now behind it.
        let out = warp_forward(&img, &depth, &k(), &translation(0.0, 0.0, -2.0));
        assert_eq!(out.holes.count(PixelClass::Known), 0);
        assert!(out.image.as_flat().iter().all(|&x| x == 0.0));
        // Turn around by 180 degrees: same.
        let turn = DMat4::from_mat3(DMat3::from_rotation_y(std::f64::consts::PI));
        assert_eq!(warp_forward(&img, &depth, &k(), &turn).holes.count(PixelClass::Known), 0);
    }

    #[test]
    fn a_pixel_of_zero_depth_goes_nowhere() {
        // Depth 0 (missing) would put every point at the camera's centre, which the motion moves
        // 2.5 units in front of the target camera, onto the principal point: nothing may land.
        let (w, h) = (40, 30);
        let depth = Image::filled(w, h, [0.0]);
        let t = translation(0.0, 0.0, 2.5);
        assert_eq!(warp_forward(&textured(w, h), &depth, &k(), &t).holes.count(PixelClass::Known), 0);
        assert!(!warp_known(&depth, &k(), &t).contains(&true));
    }

    #[test]
    fn a_point_must_be_more_than_min_z_in_front_and_finitely_far() {
        let (w, h) = (40, 30);
        let d = 2f64.powi(-20);
        let depth = Image::filled(w, h, [d as f32]);
        // Moved to exactly MIN_Z in front of the camera (MIN_Z - d is exact, as is the sum): dropped.
        let at_min_z = translation(0.0, 0.0, MIN_Z - d);
        assert_eq!(d + (MIN_Z - d), MIN_Z);
        assert!(!warp_known(&depth, &k(), &at_min_z).contains(&true));
        // A hair further lands, the same frame otherwise.
        let beyond = translation(0.0, 0.0, 2.0 * MIN_Z - d);
        assert!(warp_known(&depth, &k(), &beyond).contains(&true));
        // An infinitely far translation moves nothing anywhere.
        let infinite = translation(0.0, 0.0, f64::INFINITY);
        assert!(!warp_known(&Image::filled(w, h, [1.0]), &k(), &infinite).contains(&true));
    }

    #[test]
    fn a_point_thrown_to_infinity_does_not_set_the_largest_depth() {
        // Column 10 (cx = 10, so its points have x = 0 whatever the matrix's first column) holds a
        // near surface over a far one; moved down by 0.05, the near one lands 5 rows lower, onto
        // the far one's splats, where the depth weight, and so the largest depth, sets the blend.
        // One more point, at (30, 0) with depth 2000, lands nowhere: the matrix throws its x, its y
        // or its z to infinity. It must not count towards the largest depth, which
        // would then be 1000 instead of 10: the blend in column 10 would change.
        let (w, h) = (40, 30);
        let k = Intrinsics::new(100.0, 100.0, 10.0, 14.5);
        let img = Image::from_fn(w, h, |_, v| if v < 15 { [1.0, 0.0, 0.0] } else { [0.0, 0.0, 1.0] });
        let depth_with = |far_point: f32| {
            Image::from_fn(w, h, |u, v| match (u, v) {
                (10, v) => [if v < 15 { 1.0 } else { 10.0 }],
                (30, 0) => [far_point],
                _ => [0.0],
            })
        };
        let down = DVec3::new(0.0, 0.05, 0.0);
        let cases = [
            ("x", DVec4::new(1e306, 0.0, 0.0, 0.0)),
            ("y", DVec4::new(1.0, 1e306, 0.0, 0.0)),
            ("z", DVec4::new(1.0, 0.0, 1e306, 0.0)),
        ];
        for (case, first_column) in cases {
            let t = DMat4::from_cols(first_column, DVec4::Y, DVec4::Z, down.extend(1.0));
            let thrown = warp_forward(&img, &depth_with(2000.0), &k, &t);
            let absent = warp_forward(&img, &depth_with(0.0), &k, &t);
            // The blend is there to be changed: both surfaces reach rows 16-19 of column 10.
            let blended = absent.image.get(10, 17);
            assert!(blended[0] > 0.99 && blended[2] > 0.0, "{case}: {blended:?}");
            assert_eq!(thrown.image, absent.image, "{case} thrown to infinity changed the blend");
            assert_eq!(thrown.depth, absent.depth, "{case}");
        }
    }

    #[test]
    fn invalid_depths_never_produce_nan_or_panic() {
        let (w, h) = (17, 13);
        let img = textured(w, h);
        let specials = [f32::NAN, 0.0, -1.0, f32::INFINITY, f32::NEG_INFINITY, 1e-30, 1e30, f32::MAX, 3.0];
        let depth = Image::from_fn(w, h, |u, v| [specials[(u + v * w) % specials.len()]]);
        for t in [DMat4::IDENTITY, translation(0.3, -0.1, 0.5), translation(0.0, 0.0, -2.9)] {
            let out = warp_forward(&img, &depth, &k(), &t);
            assert!(out.image.as_flat().iter().all(|x| x.is_finite()));
            assert!(out.depth.as_flat().iter().all(|x| x.is_finite()));
        }
        let all_nan = Image::filled(w, h, [f32::NAN]);
        let out = warp_forward(&img, &all_nan, &k(), &DMat4::IDENTITY);
        assert_eq!(out.holes.count(PixelClass::NewRegion), w * h);
    }

    #[test]
    fn huge_depth_range_keeps_the_nearest_surface() {
        // A near sliver at 1e-3 in front of a wall at 1e6: near wins where both land.
        let (w, h) = (32, 24);
        let depth = Image::from_fn(w, h, |u, _| [if u == 10 { 1e-3 } else { 1e6 }]);
        let img = Image::from_fn(w, h, |u, _| if u == 10 { [1.0, 0.0, 0.0] } else { [0.0, 0.0, 1.0] });
        let out = warp_forward(&img, &depth, &k(), &DMat4::IDENTITY);
        assert_close(&out.image, &img, 1e-6);
        assert!(out.depth.as_flat().iter().all(|x| x.is_finite()));
    }

    #[test]
    fn result_does_not_depend_on_the_thread_count() {
        let (w, h) = (71, 97);
        let img = textured(w, h);
        let depth = Image::from_fn(w, h, |u, v| [1.0 + ((u * 3 + v) % 11) as f32 * 0.37]);
        let t = DMat4::from_rotation_y(0.01) * translation(0.05, 0.02, -0.03);
        let run = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| warp_forward(&img, &depth, &k(), &t))
        };
        let (a, b) = (run(1), run(3));
        assert!(a.image == b.image && a.depth == b.depth, "results differ between 1 and 3 threads");
    }

    #[test]
    fn fast_depth_weight_functions_match_libm() {
        for i in 0..10_000 {
            let x = 1.0 + (i as f32 * 0.173).powf(1.7);
            let (got, want) = (ln_at_least_one(x), x.ln());
            assert!((got - want).abs() <= 2e-7 * want.abs().max(1.0), "ln({x}) = {got} vs {want}");
            let y = -(i as f32) * 0.0087;
            let (got, want) = (exp_nonpositive(y), (y as f64).exp() as f32);
            assert!((got - want).abs() <= 3e-7 * want, "exp({y}) = {got} vs {want}");
        }
        let w = DepthWeight::new(1000.0);
        assert!((w.at(0.0) - 1.0).abs() < 1e-6);
        assert!((w.at(1e9) / (-50f32).exp() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn fast_ln_is_within_three_ulps_for_every_depth_that_occurs() {
        // Every f32 in [1, 1 + MAX_WEIGHT_DEPTH], against the f64 logarithm: measured at most
        // 2.84 ulps (the series with the sign of its last term flipped: 4.1).
        let (first, last) = (1f32.to_bits(), (1.0 + MAX_WEIGHT_DEPTH as f32).to_bits());
        let worst = (first..=last)
            .map(|bits| {
                let x = f32::from_bits(bits);
                let want = (x as f64).ln();
                let ulp = (want as f32).next_up() - want as f32;
                (ln_at_least_one(x) as f64 - want).abs() / ulp as f64
            })
            .fold(0.0, f64::max);
        assert!(worst <= 3.0, "ln_at_least_one is {worst} ulps off");
    }

    #[test]
    fn splat_field_moves_vectors_like_colours() {
        let (w, h) = (20, 10);
        let field = Image::from_fn(w, h, |u, v| [u as f32, -(v as f32)]);
        let depth = Image::filled(w, h, [5.0]);
        let (out, known) = splat_field(&field, &depth, &k(), &translation(-0.05, 0.0, 0.0));
        assert_eq!(out.get(3, 4), [4.0, -4.0]);
        assert!(!known[w - 1]);
    }

    /// The splat of ALGORITHMS.md §4 as a plain serial loop over the source pixels into one frame-sized
    /// accumulator, with the same arithmetic as `splat`: every pixel sums its splats in source
    /// order, so the two must agree to the bit.
    fn serial_splat<const C: usize>(
        field: &Image<C>,
        depth: &DepthMap,
        k: &Intrinsics,
        t: &DMat4,
    ) -> (Image<C>, DepthMap, Vec<bool>) {
        let (w, h) = (depth.width(), depth.height());
        let proj = Projector::new(w, h, k, t);
        let col = |u: usize| [0, 1, 2].map(|i| proj.col_terms[i][u]);
        let z_max = (0..w * h)
            .map(|i| proj.transform(col(i % w), &proj.row_term(i / w), depth.pixels()[i][0]))
            .filter(|(x, z_in_front)| in_front(x, *z_in_front))
            .map(|(x, _)| x[2].min(MAX_WEIGHT_DEPTH))
            .fold(0.0, f64::max);
        let points: Vec<(usize, Projection)> =
            (0..w * h).map(|i| (i, proj.project(col(i % w), &proj.row_term(i / w), depth.pixels()[i][0]))).collect();
        let weight_of_depth = DepthWeight::new(z_max);
        let (mut acc, mut depth_acc, mut weight) = (vec![[0f32; C]; w * h], vec![0f32; w * h], vec![0f32; w * h]);
        for (i, q) in points.into_iter().filter(|(_, q)| q.lands) {
            let (x0, y0) = (q.qx.floor(), q.qy.floor());
            let (ax, ay) = (q.qx - x0, q.qy - y0);
            let bilinear = [(1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay];
            for (corner, b) in bilinear.into_iter().enumerate() {
                let (tx, ty) = (x0 as i64 + (corner & 1) as i64, y0 as i64 + (corner >> 1) as i64);
                if b < MIN_BILINEAR_WEIGHT || tx < 0 || ty < 0 || tx >= w as i64 || ty >= h as i64 {
                    continue;
                }
                let wt = b as f32 * weight_of_depth.at(q.z);
                let j = ty as usize * w + tx as usize;
                weight[j] += wt;
                depth_acc[j] += wt * q.z as f32;
                for (a, v) in acc[j].iter_mut().zip(field.pixels()[i]) {
                    *a += wt * v;
                }
            }
        }
        for j in 0..w * h {
            if weight[j] > 0.0 {
                let inv = 1.0 / weight[j];
                acc[j] = acc[j].map(|x| x * inv);
                depth_acc[j] *= inv;
            }
        }
        let known = weight.iter().map(|&x| x > 0.0).collect();
        (Image::from_pixels(w, h, acc), Image::from_values(w, h, depth_acc), known)
    }

    /// Runs `f` on a pool of `threads` threads.
    fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(f)
    }

    /// Poses from none to wild: rolls and tilts make source rows reach many bands, big moves send
    /// most points out of the frame or behind the camera.
    fn poses() -> Vec<DMat4> {
        vec![
            DMat4::IDENTITY,
            DMat4::from_rotation_y(0.01) * translation(0.05, 0.02, -0.03),
            translation(-0.1, 0.0, 0.0),
            DMat4::from_rotation_z(0.5) * translation(0.1, -0.2, 0.3),
            DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2),
            DMat4::from_rotation_x(0.15) * translation(0.0, 0.05, 0.2),
            translation(0.0, 0.4, 0.0),
            translation(0.0, 3.0, 0.0),
            translation(0.0, 0.0, 2.5),
            translation(0.0, 0.0, -1.5),
            DMat4::from_rotation_y(std::f64::consts::PI),
        ]
    }

    /// A wall with boxes in front of it and holes in its depth.
    fn boxes_depth(w: usize, h: usize) -> DepthMap {
        Image::from_fn(w, h, |u, v| match (u * 7 + v * 3) % 53 {
            0 => [f32::NAN],
            1 => [0.0],
            _ if (u / 9 + v / 5) % 3 == 0 => [1.0 + (u % 4) as f32 * 0.1],
            _ => [6.0 + v as f32 * 0.01],
        })
    }

    #[test]
    fn warp_known_is_the_known_mask_of_the_warp() {
        // Odd sizes; wider than two chunks; taller than wide; a single pixel; no pixels.
        for (w, h) in [(61, 37), (CHUNK * 2 + 13, 9), (5, 7), (1, 1), (0, 3), (3, 0)] {
            let img = textured(w, h);
            let specials = [f32::NAN, 0.0, -1.0, f32::INFINITY, 1e-30, 1e30];
            let depths = [
                boxes_depth(w, h),
                Image::from_fn(w, h, |u, v| [specials[(u + v * w) % specials.len()]]),
                Image::filled(w, h, [f32::NAN]),
            ];
            for depth in &depths {
                for t in poses() {
                    let known = warp_forward(&img, depth, &k(), &t).holes.known();
                    assert_eq!(warp_known(depth, &k(), &t), known, "{w}x{h}, {t:?}");
                }
            }
        }
    }

    #[test]
    fn bands_and_chunks_give_the_bits_of_a_serial_splat() {
        // Wider than a chunk and taller than a band, with partial ones at the end; and degenerate.
        for (w, h) in
            [(CHUNK * 2 + 13, MIN_BAND_ROWS * 3 + 5), (70, 41), (1, 1), (3, 2), (1, 9), (9, 1), (0, 0), (0, 3)]
        {
            let img = textured(w, h);
            let depth = boxes_depth(w, h);
            let k = Intrinsics::new(w as f64, w as f64, w as f64 / 2.0 - 0.5, h as f64 / 2.0 - 0.5);
            for t in poses() {
                let (image, depth_out, known) = serial_splat(&img, &depth, &k, &t);
                for threads in [1, 2, 3] {
                    let out = with_threads(threads, || warp_forward(&img, &depth, &k, &t));
                    assert!(out.image == image && out.depth == depth_out, "{w}x{h}, {threads} threads, {t:?}");
                    assert_eq!(out.holes.known(), known);
                }
                // Whatever the height of the bands.
                for band_rows in [1, 2, 3, 7, MIN_BAND_ROWS, h + 1] {
                    let src = img.pixels();
                    let out = with_threads(2, || splat(&depth, &k, &t, Some(band_rows), |i| src[i]));
                    assert!(out.values == image && out.depth == depth_out && out.known == known, "{band_rows} rows");
                }
            }
        }
    }

    #[test]
    fn bands_grow_taller_when_chunks_reach_many_but_stay_in_cache() {
        let rows = |first, last| TargetRows { first, last };
        // Head motion: each chunk reaches two or three rows.
        let near: Vec<TargetRows> = (0..1080).map(|v| rows(v, (v + 2).min(1079))).collect();
        assert_eq!(band_rows(&near, 1920, 1080, 1), MIN_BAND_ROWS);
        // Every chunk reaches every row: as tall as the cache allows (8 MB of 1920 * 32 bytes).
        let far = vec![rows(0, 1079); 1080];
        assert_eq!(band_rows(&far, 1920, 1080, 1), 128);
        assert_eq!(band_rows(&far, 1920, 1080, 2), 64);
        // A small frame: one band is enough.
        assert_eq!(band_rows(&vec![rows(0, 239); 240], 320, 240, 1), 256);
        // Nothing lands, or the frame is huge.
        assert_eq!(band_rows(&[TargetRows::NONE; 10], 1920, 1080, 1), MIN_BAND_ROWS);
        assert_eq!(band_rows(&far, 1 << 20, 1080, 1), MIN_BAND_ROWS);
    }

    #[test]
    fn splat_field_of_many_channels_gives_the_bits_of_a_serial_splat() {
        // Nine channels take two accumulator blocks a pixel.
        let (w, h) = (150, 40);
        let field = Image::from_fn(w, h, |u, v| std::array::from_fn::<f32, 9, _>(|c| (u * (c + 1) + v) as f32 * 0.01));
        let depth = boxes_depth(w, h);
        for t in poses() {
            let (values, _, known) = serial_splat(&field, &depth, &k(), &t);
            assert_eq!(splat_field(&field, &depth, &k(), &t), (values, known));
        }
    }

    #[test]
    fn bit_tricks_match_the_plain_operations() {
        for x in [0.0, -0.0, 1.0, -1.0, 1919.0, -2.0e9, 3.0e12, -(2f64.powi(50))] {
            assert_eq!(integer_to_i64(x), x as i64);
        }
        for xs in
            [vec![], vec![-3.0], vec![1.0, 5.0, -2.0, 4.0, 0.5], (0..37).map(|i| ((i * 17) % 23) as f64).collect()]
        {
            assert_eq!(largest(&xs), xs.iter().copied().fold(f64::NEG_INFINITY, f64::max));
        }
        assert_eq!((select(true, 2.0, f64::NAN), select(false, f64::NAN, -0.0).to_bits()), (2.0, (-0f64).to_bits()));
    }
}
