//! Forward warping by depth-weighted bilinear splatting (SPEC §4).
//!
//! Each valid source pixel is lifted to 3-D with its depth, moved by the relative pose, projected
//! into the target view and splatted onto the four integer neighbours of where it lands. The
//! weight of a splat is the bilinear weight times a depth weight that lets the nearest surface win
//! by a factor of up to `e^50`, so the numerics follow SPEC §4 to the letter: projection in f64,
//! coordinates within [`SNAP_PX`] of an integer snapped onto it, bilinear weights below
//! [`MIN_BILINEAR_WEIGHT`] dropped.
//!
//! Work is split into fixed bands of source rows that never depend on the number of threads, and
//! bands are summed in a fixed order: the same input gives the same bits on any machine.

use glam::DMat4;
use rayon::prelude::*;

use crate::image::is_valid_depth;
use crate::{DepthMap, HoleMask, Image, Intrinsics, RgbImage};

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
/// Source rows per band: fixed, so the summation order never depends on the thread count.
const BAND_ROWS: usize = 32;

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
/// [`crate::relative_pose`]). Source and target share the intrinsics `k` and the image size.
pub fn warp_forward(image: &RgbImage, depth: &DepthMap, k: &Intrinsics, transform: &DMat4) -> Warp {
    assert!(image.same_size(depth), "image and depth differ in size");
    let src = image.pixels();
    let splat = splat(depth, k, transform, |i| src[i]);
    let holes = HoleMask::classify(image.width(), image.height(), &splat.known);
    Warp { image: splat.values, depth: splat.depth, holes }
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
    let s = splat(depth, k, transform, |i| src[i]);
    (s.values, s.known)
}

struct Splatted<const C: usize> {
    values: Image<C>,
    /// The warped planar depth, splatted like the values.
    depth: DepthMap,
    known: Vec<bool>,
}

/// The per-source-pixel part of the warp, prepared once per call.
struct Projector {
    k: Intrinsics,
    /// `R * [(u - cx) / fx, 0, 0]` for each column.
    col_term: Vec<[f64; 3]>,
    rotation_y: [f64; 3],
    rotation_z: [f64; 3],
    translation: [f64; 3],
}

impl Projector {
    fn new(width: usize, k: &Intrinsics, t: &DMat4) -> Self {
        let (rx, ry, rz) = (t.x_axis, t.y_axis, t.z_axis);
        let col_term = (0..width)
            .map(|u| {
                let a = (u as f64 - k.cx) / k.fx;
                [rx.x * a, rx.y * a, rx.z * a]
            })
            .collect();
        Self {
            k: *k,
            col_term,
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

    /// The target-camera points of row `v`, whatever their depth (callers skip invalid ones).
    /// A tight loop on its own, so that it vectorises.
    fn transform_row(&self, v: usize, depth_row: &[[f32; 1]], points: &mut [[f64; 3]]) {
        let row = self.row_term(v);
        for (u, (p, z)) in points.iter_mut().zip(depth_row).enumerate() {
            *p = self.transform(u, &row, z[0] as f64);
        }
    }

    /// The target-camera point of source pixel `(u, _)` with depth `d`, given its row term.
    #[inline]
    fn transform(&self, u: usize, row: &[f64; 3], d: f64) -> [f64; 3] {
        let c = &self.col_term[u];
        std::array::from_fn(|i| d * (c[i] + row[i]) + self.translation[i])
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

    #[inline]
    fn at(&self, z: f64) -> f32 {
        exp_nonpositive(self.scale * ln_at_least_one(1.0 + z.min(MAX_WEIGHT_DEPTH) as f32))
    }
}

/// `ln(x)` for finite `x >= 1`, relative error below 1e-7.
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
    let n = (y * std::f32::consts::LOG2_E).round();
    let r = (y - n * LN2_HI) - n * LN2_LO;
    // Taylor series of exp(r) for |r| <= ln(2)/2.
    let p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    p * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

#[inline]
fn snap(x: f64) -> f64 {
    let r = x.round();
    if (x - r).abs() < SNAP_PX {
        r
    } else {
        x
    }
}

/// A moved point is splatted only when it is finite and in front of the target camera.
#[inline]
fn is_in_front(x: &[f64; 3]) -> bool {
    x[2] > MIN_Z && x.iter().all(|c| c.is_finite())
}

/// Where a band's points land: the largest clamped depth and the target rows reached.
#[derive(Clone, Copy)]
struct BandExtent {
    z_max: f64,
    rows: Option<(usize, usize)>,
}

/// Where a point lands in the target view, or `None` when none of its four pixels is inside.
#[inline]
fn landing(k: &Intrinsics, x: &[f64; 3], w: usize, h: usize) -> Option<(f64, f64)> {
    let inv_z = 1.0 / x[2];
    let qx = snap(k.fx * x[0] * inv_z + k.cx);
    let qy = snap(k.fy * x[1] * inv_z + k.cy);
    // This also rejects infinities before any cast.
    (qx > -1.0 && qx < w as f64 && qy > -1.0 && qy < h as f64).then_some((qx, qy))
}

fn splat<const C: usize>(
    depth: &DepthMap,
    k: &Intrinsics,
    t: &DMat4,
    value: impl Fn(usize) -> [f32; C] + Sync,
) -> Splatted<C> {
    let (w, h) = (depth.width(), depth.height());
    let proj = Projector::new(w, k, t);
    let d = depth.pixels();
    let band_rows = |b: usize| b * BAND_ROWS..((b + 1) * BAND_ROWS).min(h);

    // Pass 1: the largest (clamped) depth in front of the camera, over every point, and the
    // target rows each band of source rows reaches.
    let extents: Vec<BandExtent> = (0..h.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|b| {
            let mut e = BandExtent { z_max: 0.0, rows: None };
            let mut points = vec![[0f64; 3]; w];
            for v in band_rows(b) {
                let depth_row = &d[v * w..(v + 1) * w];
                proj.transform_row(v, depth_row, &mut points);
                for (x, z) in points.iter().zip(depth_row) {
                    if !is_valid_depth(z[0]) || !is_in_front(x) {
                        continue;
                    }
                    e.z_max = e.z_max.max(x[2].min(MAX_WEIGHT_DEPTH));
                    if let Some((_, qy)) = landing(k, x, w, h) {
                        let y0 = qy.floor().max(0.0) as usize;
                        let y1 = (qy.floor() + 1.0).min(h as f64 - 1.0) as usize;
                        e.rows = Some(e.rows.map_or((y0, y1), |(a, b)| (a.min(y0), b.max(y1))));
                    }
                }
            }
            e
        })
        .collect();
    let z_max = extents.iter().map(|e| e.z_max).fold(0.0, f64::max);
    let weight_of_depth = DepthWeight::new(z_max);

    // Pass 2: splat straight into one frame-sized accumulator. Bands whose target rows overlap
    // must not run at the same time, so they run in phases: band b in phase b % phases, with the
    // fewest phases in which no two bands of a phase overlap. Each pixel then sums its splats in
    // an order fixed by the input alone, whatever the number of threads.
    let mut acc = vec![[0f32; C]; w * h];
    let mut depth_acc = vec![0f32; w * h];
    let mut weight = vec![0f32; w * h];
    let phases = (2..extents.len().max(2)).find(|&p| phases_are_disjoint(&extents, p)).unwrap_or(extents.len().max(1));
    for phase in 0..phases {
        let mut jobs: Vec<(usize, (usize, usize))> = extents
            .iter()
            .enumerate()
            .skip(phase)
            .step_by(phases)
            .filter_map(|(b, e)| e.rows.map(|r| (b, r)))
            .collect();
        jobs.sort_by_key(|&(_, (first, _))| first);
        let ranges: Vec<(usize, usize)> = jobs.iter().map(|&(_, r)| r).collect();
        let targets = carve_rows(&mut acc, w, &ranges)
            .into_iter()
            .zip(carve_rows(&mut depth_acc, w, &ranges))
            .zip(carve_rows(&mut weight, w, &ranges))
            .zip(&jobs)
            .map(|(((acc, depth), weight), &(b, (first_row, _)))| (b, BandTarget { first_row, acc, depth, weight }))
            .collect::<Vec<_>>();
        targets.into_par_iter().for_each(|(b, target)| {
            splat_band(band_rows(b), target, w, h, &proj, d, &weight_of_depth, &value);
        });
    }

    // Normalise in place.
    let known: Vec<bool> = weight.iter().map(|&x| x > 0.0).collect();
    acc.par_iter_mut().zip(depth_acc.par_iter_mut()).zip(weight.par_iter()).for_each(|((a, z), &wt)| {
        if wt > 0.0 {
            let inv = 1.0 / wt;
            *a = a.map(|x| x * inv);
            *z *= inv;
        }
    });
    Splatted { values: Image::from_pixels(w, h, acc), depth: Image::from_values(w, h, depth_acc), known }
}

/// Mutable slices of the rows `first..=last` of each range (sorted, disjoint) of a row-major buffer.
fn carve_rows<'a, T>(mut buf: &'a mut [T], width: usize, ranges: &[(usize, usize)]) -> Vec<&'a mut [T]> {
    let mut slices = Vec::with_capacity(ranges.len());
    let mut consumed = 0;
    for &(first, last) in ranges {
        let (_, rest) = std::mem::take(&mut buf).split_at_mut((first - consumed) * width);
        let (rows, rest) = rest.split_at_mut((last + 1 - first) * width);
        slices.push(rows);
        (buf, consumed) = (rest, last + 1);
    }
    slices
}

/// True when, taking every `phases`-th band, no two bands reach the same target row.
fn phases_are_disjoint(extents: &[BandExtent], phases: usize) -> bool {
    (0..phases).all(|phase| {
        let mut ranges: Vec<(usize, usize)> =
            extents.iter().skip(phase).step_by(phases).filter_map(|e| e.rows).collect();
        ranges.sort_unstable();
        ranges.windows(2).all(|r| r[0].1 < r[1].0)
    })
}

/// The accumulator rows `first_row..` that one band splats into.
struct BandTarget<'a, const C: usize> {
    first_row: usize,
    acc: &'a mut [[f32; C]],
    depth: &'a mut [f32],
    weight: &'a mut [f32],
}

#[allow(clippy::too_many_arguments)]
fn splat_band<const C: usize>(
    rows: std::ops::Range<usize>,
    target: BandTarget<'_, C>,
    w: usize,
    h: usize,
    proj: &Projector,
    d: &[[f32; 1]],
    weight_of_depth: &DepthWeight,
    value: &(impl Fn(usize) -> [f32; C] + Sync),
) {
    let BandTarget { first_row, acc, depth: depth_acc, weight } = target;
    let k = &proj.k;
    // Row by row: transform and weigh every point in tight loops that vectorise, then splat.
    let mut points = vec![[0f64; 3]; w];
    let mut depth_weights = vec![0f32; w];
    for v in rows {
        let depth_row = &d[v * w..(v + 1) * w];
        proj.transform_row(v, depth_row, &mut points);
        for (wd, p) in depth_weights.iter_mut().zip(&points) {
            *wd = weight_of_depth.at(p[2]);
        }
        for u in 0..w {
            let (i, x) = (v * w + u, points[u]);
            if !is_valid_depth(depth_row[u][0]) || !is_in_front(&x) {
                continue;
            }
            let Some((qx, qy)) = landing(k, &x, w, h) else { continue };
            let (fx0, fy0) = (qx.floor(), qy.floor());
            let (ax, ay) = (qx - fx0, qy - fy0);
            let bilinear = [(1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay];
            let wd = depth_weights[u];
            let (val, z) = (value(i), x[2] as f32);
            let (x0, y0) = (fx0 as i64, fy0 as i64);
            for (corner, &b) in bilinear.iter().enumerate() {
                let tx = x0 + (corner & 1) as i64;
                let ty = y0 + (corner >> 1) as i64;
                if b < MIN_BILINEAR_WEIGHT || tx < 0 || ty < 0 || tx >= w as i64 || ty >= h as i64 {
                    continue;
                }
                let wt = b as f32 * wd;
                let j = (ty as usize - first_row) * w + tx as usize;
                weight[j] += wt;
                depth_acc[j] += wt * z;
                for (a, v) in acc[j].iter_mut().zip(val) {
                    *a += wt * v;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PixelClass;
    use glam::{DMat3, DVec3};

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
    fn splat_field_moves_vectors_like_colours() {
        let (w, h) = (20, 10);
        let field = Image::from_fn(w, h, |u, v| [u as f32, -(v as f32)]);
        let depth = Image::filled(w, h, [5.0]);
        let (out, known) = splat_field(&field, &depth, &k(), &translation(-0.05, 0.0, 0.0));
        assert_eq!(out.get(3, 4), [4.0, -4.0]);
        assert!(!known[w - 1]);
    }
}
