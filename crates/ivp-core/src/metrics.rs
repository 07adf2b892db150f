//! Metrics of ALGORITHMS.md §7: MSE, SSIM, D-MSE, D-SSIM and temporal consistency.
//!
//! Every metric is on the 8-bit scale: image values in `[0, 1]` are multiplied by 255. All sums run
//! in f64, and every parallel loop writes to fixed slots (no parallel float reduction), so results
//! are bit-for-bit reproducible whatever the thread count.
//!
//! The SSIM parameters (window, sigma, `K1`, `K2`) are defined here once; the SSIM loss of `nn`
//! uses the same ones on the 0..1 scale.
//!
//! Layer: imports `geometry` only.

use glam::DVec2;
use rayon::prelude::*;

use crate::geometry::camera::{transform_point, Intrinsics, WorldToCamera};
use crate::geometry::image::{is_valid_depth, DepthMap, RgbImage};

/// Image values are multiplied by this before scoring (metrics are on 0..255).
const SCALE: f64 = 255.0;

/// Radius of the SSIM window (11x11).
pub const SSIM_RADIUS: usize = 5;
/// Side of the SSIM window.
pub const SSIM_WINDOW: usize = 2 * SSIM_RADIUS + 1;
/// Standard deviation of the SSIM Gaussian, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM's luminance constant is `(K1 L)^2` for values of dynamic range `L`.
pub const SSIM_K1: f64 = 0.01;
/// SSIM's contrast constant is `(K2 L)^2` for values of dynamic range `L`.
pub const SSIM_K2: f64 = 0.03;
/// SSIM's luminance constant for values of dynamic range `range`.
pub const fn ssim_c1(range: f64) -> f64 {
    (SSIM_K1 * range) * (SSIM_K1 * range)
}
/// SSIM's contrast constant for values of dynamic range `range`.
pub const fn ssim_c2(range: f64) -> f64 {
    (SSIM_K2 * range) * (SSIM_K2 * range)
}
/// SSIM's luminance constant on the 0..255 scale: `(0.01 * 255)^2`.
pub const SSIM_C1: f64 = ssim_c1(SCALE);
/// SSIM's contrast constant on the 0..255 scale: `(0.03 * 255)^2`.
pub const SSIM_C2: f64 = ssim_c2(SCALE);

/// Neighbourhood of the TC tracks: offsets with `|dx|, |dy| <= TC_RADIUS` (ALGORITHMS.md §7).
pub const TC_RADIUS: isize = 8;

// ---------------------------------------------------------------------------------------------
// MSE
// ---------------------------------------------------------------------------------------------

/// Mean squared error on the 0..255 scale, over every pixel and channel.
///
/// Empty images give NaN (there is nothing to average). Panics if the sizes differ.
pub fn mse(pred: &RgbImage, gt: &RgbImage) -> f64 {
    assert_same_size(pred, gt);
    let w = pred.width().max(1);
    // One sum per row, added up serially: parallel and still deterministic.
    let rows: Vec<f64> = pred
        .pixels()
        .par_chunks(w)
        .zip(gt.pixels().par_chunks(w))
        .map(|(p, g)| p.iter().zip(g).map(|(p, g)| squared_error(p, g)).sum())
        .collect();
    rows.iter().sum::<f64>() / (3 * pred.len()) as f64
}

/// MSE (0..255 scale) over the pixels where `mask` is true; `None` when the mask selects nothing.
///
/// Panics if the sizes differ or `mask` does not have one entry per pixel.
pub fn masked_mse(pred: &RgbImage, gt: &RgbImage, mask: &[bool]) -> Option<f64> {
    assert_same_size(pred, gt);
    assert_eq!(mask.len(), pred.len(), "mask has {} entries for {} pixels", mask.len(), pred.len());
    let (sum, count) = pred
        .pixels()
        .iter()
        .zip(gt.pixels())
        .zip(mask)
        .filter(|(_, &m)| m)
        .fold((0.0, 0usize), |(s, n), ((p, g), _)| (s + squared_error(p, g), n + 1));
    (count > 0).then(|| sum / (3 * count) as f64)
}

/// Sum over the three channels of the squared difference, on 0..255.
#[inline]
fn squared_error(p: &[f32; 3], g: &[f32; 3]) -> f64 {
    p.iter()
        .zip(g)
        .map(|(&p, &g)| {
            let d = (p as f64 - g as f64) * SCALE;
            d * d
        })
        .sum()
}

/// Mean of `values` over the entries where `mask` is true; `None` when the mask selects nothing.
pub fn masked_mean(values: &[f64], mask: &[bool]) -> Option<f64> {
    assert_eq!(values.len(), mask.len(), "{} values for a mask of {}", values.len(), mask.len());
    let (sum, count) =
        values.iter().zip(mask).filter(|(_, &m)| m).fold((0.0, 0usize), |(s, n), (&x, _)| (s + x, n + 1));
    (count > 0).then(|| sum / count as f64)
}

// ---------------------------------------------------------------------------------------------
// SSIM
// ---------------------------------------------------------------------------------------------

/// Folds any integer index into `0..n` by mirroring at the borders without repeating the edge
/// sample (numpy `reflect` = OpenCV `BORDER_REFLECT_101` = scipy.ndimage `mirror`):
/// `-1 -> 1`, `-2 -> 2`, `n -> n - 2`. The mirror is applied repeatedly, so any index is valid
/// even when the image is smaller than the filter (the sequence is periodic with period
/// `2 (n - 1)`). With `n == 1` every index maps to 0. Panics if `n == 0`.
#[inline]
pub fn reflect_101(i: isize, n: usize) -> usize {
    assert!(n > 0, "reflect_101 on an empty axis");
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let j = i.rem_euclid(period);
    (if j < n as isize { j } else { period - j }) as usize
}

/// The normalised 1-D Gaussian of the SSIM window (11 taps, sigma 1.5). The 2-D window is its
/// outer product with itself, which is why the filtering can be done separably.
pub fn ssim_kernel() -> [f64; SSIM_WINDOW] {
    let mut g = [0.0; SSIM_WINDOW];
    for (k, gk) in g.iter_mut().enumerate() {
        let x = k as f64 - SSIM_RADIUS as f64;
        *gk = (-x * x / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let sum: f64 = g.iter().sum();
    g.map(|x| x / sum)
}

/// Local moments filtered per pixel: for each channel `c`, slots `5c..5c+5` hold
/// `a, b, a^2, b^2, a*b` (a = prediction, b = ground truth, on 0..255).
const MOMENTS: usize = 15;
type Moments = [f64; MOMENTS];

/// Rows of output computed by one parallel task. Each task filters `2 * SSIM_RADIUS` extra rows
/// horizontally, so larger tasks waste less; 64 still leaves 17 tasks for a 1080-row frame.
const ROWS_PER_TASK: usize = 64;

/// The SSIM map (ALGORITHMS.md §7), one value per pixel, row-major, averaged over the three channels.
///
/// Standard SSIM on 0..255 values: Gaussian window 11x11 with sigma 1.5, borders mirrored without
/// repeating the edge pixel ([`reflect_101`]), biased local variances `E[x^2] - mu^2`,
/// `((2 mu_a mu_b + C1)(2 cov + C2)) / ((mu_a^2 + mu_b^2 + C1)(var_a + var_b + C2))` with
/// `C1 = (0.01*255)^2`, `C2 = (0.03*255)^2`. No border crop: the map covers the whole frame.
///
/// Computed in f64 (the `E[x^2] - mu^2` difference cancels catastrophically in f32) with separable
/// filtering, parallel over bands of rows. Panics if the sizes differ.
pub fn ssim_map(pred: &RgbImage, gt: &RgbImage) -> Vec<f64> {
    assert_same_size(pred, gt);
    let (w, h) = (pred.width(), pred.height());
    let mut map = vec![0.0; w * h];
    if w == 0 || h == 0 {
        return map;
    }
    let g = ssim_kernel();
    map.par_chunks_mut(ROWS_PER_TASK * w)
        .enumerate()
        .for_each(|(task, out)| ssim_rows(pred, gt, &g, task * ROWS_PER_TASK, out));
    map
}

/// Mean SSIM over the whole frame (the mean of [`ssim_map`]). NaN for empty images.
pub fn ssim(pred: &RgbImage, gt: &RgbImage) -> f64 {
    let map = ssim_map(pred, gt);
    map.iter().sum::<f64>() / map.len() as f64
}

/// Mean of the SSIM map over the pixels where `mask` is true (D-SSIM with the disocclusion mask);
/// `None` when the mask selects nothing.
pub fn masked_ssim(pred: &RgbImage, gt: &RgbImage, mask: &[bool]) -> Option<f64> {
    assert_eq!(mask.len(), pred.len(), "mask has {} entries for {} pixels", mask.len(), pred.len());
    masked_mean(&ssim_map(pred, gt), mask)
}

/// SSIM of output rows `v0 .. v0 + out.len() / w`.
///
/// Horizontally filtered rows go through a ring buffer of `SSIM_WINDOW` rows: output row `v`
/// needs the source rows `v - 5 ..= v + 5` (mirrored), which are the last 11 rows filtered when it
/// is computed. This keeps the working set small (11 rows) whatever the band height.
fn ssim_rows(pred: &RgbImage, gt: &RgbImage, g: &[f64; SSIM_WINDOW], v0: usize, out: &mut [f64]) {
    let (w, h) = (pred.width(), pred.height());
    let rows = out.len() / w;
    let r = SSIM_RADIUS;
    let mut padded = vec![[0.0; MOMENTS]; w + 2 * r];
    let mut ring = vec![[0.0; MOMENTS]; SSIM_WINDOW * w];
    let mut acc = vec![[0.0; MOMENTS]; w];
    // Filtered row k of this band is the (mirrored) source row of virtual index v0 - r + k.
    for k in 0..rows + 2 * r {
        let y = reflect_101(v0 as isize - r as isize + k as isize, h);
        let slot = k % SSIM_WINDOW;
        filter_row(pred, gt, y, g, &mut padded, &mut ring[slot * w..(slot + 1) * w]);
        if k < 2 * r {
            continue;
        }
        // Output row v0 + i uses band rows i ..= i + 2r, the last 11 filtered.
        let i = k - 2 * r;
        acc.fill([0.0; MOMENTS]);
        for (t, &gk) in g.iter().enumerate() {
            let slot = (i + t) % SSIM_WINDOW;
            for (a, m) in acc.iter_mut().zip(&ring[slot * w..(slot + 1) * w]) {
                for q in 0..MOMENTS {
                    a[q] += gk * m[q];
                }
            }
        }
        for (o, m) in out[i * w..(i + 1) * w].iter_mut().zip(&acc) {
            *o = ssim_from_moments(m);
        }
    }
}

/// Horizontally filters the moments of source row `y` into `dst` (one entry per column).
fn filter_row(
    pred: &RgbImage,
    gt: &RgbImage,
    y: usize,
    g: &[f64; SSIM_WINDOW],
    padded: &mut [Moments],
    dst: &mut [Moments],
) {
    let w = pred.width();
    let (prow, grow) = (pred.row(y), gt.row(y));
    for (i, p) in padded.iter_mut().enumerate() {
        let x = reflect_101(i as isize - SSIM_RADIUS as isize, w);
        for c in 0..3 {
            let a = prow[x][c] as f64 * SCALE;
            let b = grow[x][c] as f64 * SCALE;
            p[5 * c..5 * c + 5].copy_from_slice(&[a, b, a * a, b * b, a * b]);
        }
    }
    for (u, d) in dst.iter_mut().enumerate() {
        let mut s = [0.0; MOMENTS];
        for (t, &gk) in g.iter().enumerate() {
            let m = &padded[u + t];
            for q in 0..MOMENTS {
                s[q] += gk * m[q];
            }
        }
        *d = s;
    }
}

/// Channel-averaged SSIM from the filtered local moments of one pixel.
#[inline]
fn ssim_from_moments(m: &Moments) -> f64 {
    let mut sum = 0.0;
    for c in 0..3 {
        let [mu_a, mu_b, e_aa, e_bb, e_ab] = [m[5 * c], m[5 * c + 1], m[5 * c + 2], m[5 * c + 3], m[5 * c + 4]];
        let var_a = e_aa - mu_a * mu_a;
        let var_b = e_bb - mu_b * mu_b;
        let cov = e_ab - mu_a * mu_b;
        sum += ((2.0 * mu_a * mu_b + SSIM_C1) * (2.0 * cov + SSIM_C2))
            / ((mu_a * mu_a + mu_b * mu_b + SSIM_C1) * (var_a + var_b + SSIM_C2));
    }
    sum / 3.0
}

// ---------------------------------------------------------------------------------------------
// Per-frame scores
// ---------------------------------------------------------------------------------------------

/// The scores of one predicted frame (ALGORITHMS.md §7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameScores {
    /// MSE over the whole frame, 0..255 scale.
    pub mse: f64,
    /// Mean SSIM over the whole frame.
    pub ssim: f64,
    /// MSE over the disocclusion pixels; `None` when the frame has none.
    pub d_mse: Option<f64>,
    /// Mean of the SSIM map over the disocclusion pixels; `None` when the frame has none.
    pub d_ssim: Option<f64>,
    /// Number of disocclusion pixels.
    pub disocclusion_pixels: usize,
}

/// Scores a prediction against its ground truth; `disocclusions` is the disocclusion mask of the
/// warp that produced the prediction (row-major, one entry per pixel).
///
/// The caller rounds `pred` to 8 bits first ([`RgbImage::quantized_to_8bit`]) so that in-tool and
/// exported predictions score the same; this function scores exactly what it is given.
pub fn score_frame(pred: &RgbImage, gt: &RgbImage, disocclusions: &[bool]) -> FrameScores {
    assert_eq!(disocclusions.len(), pred.len(), "mask has {} entries for {} pixels", disocclusions.len(), pred.len());
    let map = ssim_map(pred, gt);
    FrameScores {
        mse: mse(pred, gt),
        ssim: map.iter().sum::<f64>() / map.len() as f64,
        d_mse: masked_mse(pred, gt, disocclusions),
        d_ssim: masked_mean(&map, disocclusions),
        disocclusion_pixels: disocclusions.iter().filter(|&&d| d).count(),
    }
}

// ---------------------------------------------------------------------------------------------
// Temporal consistency
// ---------------------------------------------------------------------------------------------

/// One clip's frames for temporal consistency. Every slice indexes the same frame sequence (for
/// the evaluation of ALGORITHMS.md §5: frames 5..=11, predicted at 6, 8 and 10, so index 0 is frame 5).
pub struct TcSequence<'a> {
    pub intrinsics: &'a Intrinsics,
    /// Ground-truth world-to-camera pose of every frame.
    pub poses: &'a [WorldToCamera],
    /// Ground-truth image of every frame.
    pub ground_truth: &'a [RgbImage],
    /// `Some(prediction)` at the predicted frames, `None` at the ground-truth frames.
    pub predictions: &'a [Option<RgbImage>],
    /// `Some(mask)` exactly at the predicted frames: the disocclusion mask of the warp that
    /// produced that prediction (row-major).
    pub disocclusions: &'a [Option<Vec<bool>>],
    /// Warped depth of the first predicted frame (the anchors' depth).
    pub anchor_depth: &'a DepthMap,
    /// Known mask of the warp of the first predicted frame (row-major).
    pub anchor_known: &'a [bool],
}

/// The population variance of the error sequence of every kept TC track of one clip (ALGORITHMS.md §7);
/// TC is the mean of these over all tracks of a dataset pooled together, and is absent (not 0)
/// when there are no tracks. The output order is deterministic (anchors row-major, then offsets
/// row-major, `dy` outer and `dx` inner).
///
/// Exact reading, with `f` the first predicted frame of the sequence:
/// - **Anchors**: pixels `a` known in frame `f`'s warp (`anchor_known`) with a valid warped depth
///   and with a disocclusion pixel of frame `f` among their 8 in-frame neighbours.
/// - **Point track**: `X = inverse(E_f) * unproject(a, depth(a))` in world space; for every frame
///   `t`, `p_t = project(E_t * X)`, and `p_f = a` exactly. An anchor whose point is behind any
///   camera (`z <= 0`) or projects to a non-finite position gives no tracks.
/// - **Tracks**: for each offset `delta = d - a` to a disocclusion pixel `d` of frame `f` with
///   `|dx|, |dy| <= 8`, `q_t = round(p_t + delta)` per coordinate (half away from zero). The
///   track is kept only if `q_t` is inside the frame for every frame of the sequence and is a
///   disocclusion pixel of frame `t` at every predicted frame `t`.
/// - **Errors**: `e_t = mean_c |pred_t(q_t) - gt_t(q_t)| * 255` at predicted frames and `e_t = 0`
///   at ground-truth frames; the result is `mean_t (e_t - mean(e))^2` over the whole sequence.
///
/// A sequence with no predicted frame gives no tracks. Panics if the slices have different
/// lengths, the masks or images have different sizes, or `predictions` and `disocclusions`
/// disagree on which frames are predicted.
pub fn tc_track_variances(seq: &TcSequence) -> Vec<f64> {
    let n = seq.ground_truth.len();
    assert!(
        seq.poses.len() == n && seq.predictions.len() == n && seq.disocclusions.len() == n,
        "TC sequence: {} poses, {} ground-truth frames, {} predictions, {} masks",
        seq.poses.len(),
        n,
        seq.predictions.len(),
        seq.disocclusions.len()
    );
    let Some(first) = seq.predictions.iter().position(Option::is_some) else {
        return Vec::new();
    };
    let (w, h) = (seq.ground_truth[0].width(), seq.ground_truth[0].height());
    for t in 0..n {
        assert!(seq.ground_truth[t].width() == w && seq.ground_truth[t].height() == h, "TC: frame sizes differ");
        assert_eq!(
            seq.predictions[t].is_some(),
            seq.disocclusions[t].is_some(),
            "TC: frame {t} has a prediction without a mask or a mask without a prediction"
        );
        if let (Some(p), Some(d)) = (&seq.predictions[t], &seq.disocclusions[t]) {
            assert_same_size(p, &seq.ground_truth[t]);
            assert_eq!(d.len(), w * h, "TC: disocclusion mask of frame {t} has the wrong size");
        }
    }
    assert!(seq.anchor_depth.width() == w && seq.anchor_depth.height() == h, "TC: anchor depth size differs");
    assert_eq!(seq.anchor_known.len(), w * h, "TC: anchor known mask has the wrong size");

    // Per-pixel error e_t of each predicted frame, computed once instead of once per track.
    let errors: Vec<Option<Vec<f64>>> = seq
        .predictions
        .iter()
        .zip(seq.ground_truth)
        .map(|(p, g)| p.as_ref().map(|p| mean_abs_error_map(p, g)))
        .collect();
    let anchor_disocc = seq.disocclusions[first].as_deref().expect("checked above");
    let is_disocc = |u: isize, v: isize| {
        u >= 0 && v >= 0 && (u as usize) < w && (v as usize) < h && anchor_disocc[v as usize * w + u as usize]
    };

    let anchors: Vec<(usize, usize)> = (0..h)
        .flat_map(|v| (0..w).map(move |u| (u, v)))
        .filter(|&(u, v)| {
            seq.anchor_known[v * w + u]
                && is_valid_depth(seq.anchor_depth.at(u, v))
                && (-1..=1).any(|dy| (-1..=1).any(|dx| is_disocc(u as isize + dx, v as isize + dy)))
        })
        .collect();

    let cam_to_world = seq.poses[first].camera_to_world();
    let per_anchor: Vec<Vec<f64>> = anchors
        .par_iter()
        .map(|&(u, v)| {
            let z = seq.anchor_depth.at(u, v) as f64;
            let world = transform_point(&cam_to_world, seq.intrinsics.unproject(u as f64, v as f64, z));
            let mut p = Vec::with_capacity(n);
            for (t, pose) in seq.poses.iter().enumerate() {
                // In its own frame the anchor is where it is: no round-trip error can move it.
                let pt = if t == first {
                    DVec2::new(u as f64, v as f64)
                } else {
                    match seq.intrinsics.project(transform_point(&pose.0, world)) {
                        Some(pt) => pt,
                        None => return Vec::new(),
                    }
                };
                p.push(pt);
            }
            let mut variances = Vec::new();
            let mut e = vec![0.0; n];
            for dy in -TC_RADIUS..=TC_RADIUS {
                for dx in -TC_RADIUS..=TC_RADIUS {
                    if !is_disocc(u as isize + dx, v as isize + dy) {
                        continue;
                    }
                    let delta = DVec2::new(dx as f64, dy as f64);
                    let kept = p.iter().enumerate().all(|(t, &pt)| {
                        let q = (pt + delta).round();
                        // Written so that NaN fails too.
                        if !(q.x >= 0.0 && q.y >= 0.0 && q.x < w as f64 && q.y < h as f64) {
                            return false;
                        }
                        let i = q.y as usize * w + q.x as usize;
                        match (&errors[t], &seq.disocclusions[t]) {
                            (Some(err), Some(mask)) => {
                                e[t] = err[i];
                                mask[i]
                            }
                            _ => {
                                e[t] = 0.0;
                                true
                            }
                        }
                    });
                    if kept {
                        variances.push(population_variance(&e));
                    }
                }
            }
            variances
        })
        .collect();
    per_anchor.concat()
}

/// `mean_c |pred - gt| * 255` per pixel.
fn mean_abs_error_map(pred: &RgbImage, gt: &RgbImage) -> Vec<f64> {
    pred.pixels()
        .iter()
        .zip(gt.pixels())
        .map(|(p, g)| p.iter().zip(g).map(|(&p, &g)| (p as f64 - g as f64).abs()).sum::<f64>() * SCALE / 3.0)
        .collect()
}

/// `mean (x - mean x)^2` (population variance, no N/(N-1) correction).
fn population_variance(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    x.iter().map(|&v| (v - mean) * (v - mean)).sum::<f64>() / n
}

fn assert_same_size(a: &RgbImage, b: &RgbImage) {
    assert!(
        a.width() == b.width() && a.height() == b.height(),
        "image sizes differ: {}x{} vs {}x{}",
        a.width(),
        a.height(),
        b.width(),
        b.height()
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat4, DVec3};

    /// A small deterministic generator (xorshift64*) so that tests need no extra crate.
    struct Rng(u64);

    impl Rng {
        fn next_f32(&mut self) -> f32 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40) as f32 / (1u64 << 24) as f32
        }

        /// A random image on the 8-bit grid, like every scored prediction.
        fn image(&mut self, w: usize, h: usize) -> RgbImage {
            let pixels = (0..w * h).map(|_| [(); 3].map(|_| (self.next_f32() * 255.0).round() / 255.0)).collect();
            RgbImage::from_pixels(w, h, pixels)
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn mse_of_constant_images_10_levels_apart_is_100() {
        let a = RgbImage::filled(7, 5, [0.0; 3]);
        let b = RgbImage::filled(7, 5, [10.0 / 255.0; 3]);
        assert!(close(mse(&a, &b), 100.0, 1e-4), "{}", mse(&a, &b));
        assert_eq!(mse(&a, &a), 0.0);
        // 0.25 -> 63.75 exactly on the 8-bit scale.
        let c = RgbImage::filled(3, 2, [0.25, 0.25, 0.0]);
        let d = RgbImage::filled(3, 2, [0.0; 3]);
        assert_eq!(mse(&c, &d), 2.0 * 63.75 * 63.75 / 3.0);
    }

    #[test]
    fn masked_mse_uses_only_masked_pixels_and_is_none_when_empty() {
        let a = RgbImage::filled(4, 1, [0.0; 3]);
        let b = RgbImage::from_fn(4, 1, |u, _| if u == 2 { [0.25; 3] } else { [0.5; 3] });
        assert_eq!(masked_mse(&a, &b, &[false, false, true, false]), Some(63.75 * 63.75));
        assert_eq!(masked_mse(&a, &b, &[false; 4]), None);
        assert_eq!(masked_ssim(&a, &b, &[false; 4]), None);
        assert_eq!(masked_mean(&[1.0, 2.0, 4.0], &[true, false, true]), Some(2.5));
        assert_eq!(masked_mean(&[], &[]), None);
        // Several pixels, neither image zero: 1, 2 and 3 levels apart in one channel each.
        let p = RgbImage::from_fn(3, 1, |u, _| {
            [[10.0, 20.0, 30.0], [40.0, 50.0, 60.0], [70.0, 80.0, 90.0]][u].map(|x| x / 255.0)
        });
        let g = RgbImage::from_fn(3, 1, |u, _| {
            [[11.0, 20.0, 30.0], [40.0, 48.0, 60.0], [70.0, 80.0, 93.0]][u].map(|x| x / 255.0)
        });
        let by_hand = (1.0 + 4.0 + 9.0) / 9.0;
        assert!(close(masked_mse(&p, &g, &[true; 3]).unwrap(), by_hand, 1e-4), "{:?}", masked_mse(&p, &g, &[true; 3]));
        assert!(close(mse(&p, &g), by_hand, 1e-4), "{}", mse(&p, &g));
    }

    #[test]
    fn masked_ssim_is_the_mean_of_the_map_over_the_mask() {
        let mut rng = Rng(11);
        let (a, b) = (rng.image(9, 7), rng.image(9, 7));
        let map = ssim_map(&a, &b);
        let mask: Vec<bool> = (0..map.len()).map(|i| i % 3 == 0).collect();
        let by_hand = masked_mean(&map, &mask).unwrap();
        assert!(by_hand < 0.5, "random images are far apart: {by_hand}");
        assert_eq!(masked_ssim(&a, &b, &mask), Some(by_hand));
        assert_eq!(masked_ssim(&a, &a, &mask).map(|s| (s * 1e9).round() / 1e9), Some(1.0));
    }

    #[test]
    fn images_without_pixels_have_an_empty_ssim_map() {
        for (w, h) in [(0, 0), (0, 5), (5, 0)] {
            let a = RgbImage::filled(w, h, [0.5; 3]);
            assert!(ssim_map(&a, &a).is_empty(), "{w}x{h}");
        }
    }

    #[test]
    fn reflect_101_mirrors_without_repeating_the_edge() {
        assert_eq!(reflect_101(-1, 5), 1);
        assert_eq!(reflect_101(-2, 5), 2);
        assert_eq!(reflect_101(5, 5), 3);
        assert_eq!(reflect_101(6, 5), 2);
        assert_eq!(reflect_101(0, 5), 0);
        assert_eq!(reflect_101(4, 5), 4);
        // Repeated mirroring when the pad exceeds the size (indices -5..=7): period 2 (n - 1) = 4.
        let folded: Vec<usize> = (-5..=7).map(|i| reflect_101(i, 3)).collect();
        assert_eq!(folded, [1, 0, 1, 2, 1, 0, 1, 2, 1, 0, 1, 2, 1]);
        for i in -12..12 {
            assert_eq!(reflect_101(i, 1), 0);
            assert_eq!(reflect_101(i, 2), i.rem_euclid(2) as usize);
        }
    }

    #[test]
    fn ssim_kernel_is_normalised_and_symmetric() {
        let g = ssim_kernel();
        assert!(close(g.iter().sum(), 1.0, 1e-15));
        for k in 0..SSIM_WINDOW {
            assert_eq!(g[k], g[SSIM_WINDOW - 1 - k]);
        }
        assert!(close(g[6] / g[5], (-1.0f64 / 4.5).exp(), 1e-15));
    }

    #[test]
    fn ssim_of_identical_images_is_one() {
        let mut rng = Rng(7);
        for (w, h) in [(23, 17), (3, 3), (1, 9), (9, 1), (1, 1), (2, 2), (70, 130)] {
            let a = rng.image(w, h);
            let map = ssim_map(&a, &a);
            assert_eq!(map.len(), w * h);
            assert!(map.iter().all(|&s| close(s, 1.0, 1e-12)), "{w}x{h}");
            assert!(close(ssim(&a, &a), 1.0, 1e-12));
        }
    }

    #[test]
    fn ssim_of_constant_images_is_the_luminance_term() {
        for (w, h) in [(1, 1), (1, 4), (3, 3), (15, 12)] {
            let a = RgbImage::filled(w, h, [0.5; 3]);
            assert_eq!(ssim(&a, &a), 1.0);
            let b = RgbImage::filled(w, h, [0.25; 3]);
            let (x, y) = (127.5, 63.75);
            let expected = (2.0 * x * y + SSIM_C1) / (x * x + y * y + SSIM_C1);
            assert!(map_all_close(&ssim_map(&a, &b), expected, 1e-12), "{w}x{h}");
        }
    }

    fn map_all_close(map: &[f64], expected: f64, tol: f64) -> bool {
        map.iter().all(|&s| close(s, expected, tol))
    }

    /// Mirror index folded one step at a time, independently of [`reflect_101`].
    fn reflect_slow(mut i: isize, n: usize) -> usize {
        let n = n as isize;
        if n == 1 {
            return 0;
        }
        loop {
            if i < 0 {
                i = -i;
            } else if i >= n {
                i = 2 * (n - 1) - i;
            } else {
                return i as usize;
            }
        }
    }

    /// Textbook SSIM map: direct 2-D Gaussian window, every sum written out.
    fn ssim_map_slow(a: &RgbImage, b: &RgbImage) -> Vec<f64> {
        let (w, h) = (a.width(), a.height());
        let mut win = [[0.0; 11]; 11];
        let mut total = 0.0;
        for (j, row) in win.iter_mut().enumerate() {
            for (i, x) in row.iter_mut().enumerate() {
                let (dx, dy) = (i as f64 - 5.0, j as f64 - 5.0);
                *x = (-(dx * dx + dy * dy) / (2.0 * 1.5 * 1.5)).exp();
                total += *x;
            }
        }
        let c1 = (0.01f64 * 255.0).powi(2);
        let c2 = (0.03f64 * 255.0).powi(2);
        let mut map = vec![0.0; w * h];
        for v in 0..h {
            for u in 0..w {
                let mut s = 0.0;
                for c in 0..3 {
                    let (mut ma, mut mb, mut aa, mut bb, mut ab) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for (j, win_row) in win.iter().enumerate() {
                        for (i, &win_ji) in win_row.iter().enumerate() {
                            let x = reflect_slow(u as isize + i as isize - 5, w);
                            let y = reflect_slow(v as isize + j as isize - 5, h);
                            let wt = win_ji / total;
                            let va = a.get(x, y)[c] as f64 * 255.0;
                            let vb = b.get(x, y)[c] as f64 * 255.0;
                            ma += wt * va;
                            mb += wt * vb;
                            aa += wt * va * va;
                            bb += wt * vb * vb;
                            ab += wt * va * vb;
                        }
                    }
                    let (sa, sb, sab) = (aa - ma * ma, bb - mb * mb, ab - ma * mb);
                    s += (2.0 * ma * mb + c1) * (2.0 * sab + c2) / ((ma * ma + mb * mb + c1) * (sa + sb + c2));
                }
                map[v * w + u] = s / 3.0;
            }
        }
        map
    }

    #[test]
    fn ssim_matches_a_direct_2d_implementation() {
        let mut rng = Rng(12345);
        // 23x17 is the main case; the others are smaller than the window or a single line, and
        // 70x150 spans several parallel bands.
        for (w, h) in [(23, 17), (3, 3), (1, 7), (7, 1), (2, 2), (1, 1), (4, 13), (70, 150)] {
            let a = rng.image(w, h);
            let b = rng.image(w, h);
            let fast = ssim_map(&a, &b);
            let slow = ssim_map_slow(&a, &b);
            let worst = fast.iter().zip(&slow).map(|(f, s)| (f - s).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-9, "{w}x{h}: max difference {worst}");
        }
    }

    #[test]
    fn ssim_is_deterministic_and_bands_agree() {
        let mut rng = Rng(99);
        let (a, b) = (rng.image(50, 200), rng.image(50, 200));
        let m1 = ssim_map(&a, &b);
        let m2 = ssim_map(&a, &b);
        assert_eq!(m1, m2);
        assert!(m1.iter().all(|&s| s > -1.0 && s < 1.0));
    }

    #[test]
    fn score_frame_combines_whole_and_disocclusion_scores() {
        let mut rng = Rng(3);
        let (a, b) = (rng.image(30, 20), rng.image(30, 20));
        let mut mask = vec![false; 600];
        mask[100..110].iter_mut().for_each(|m| *m = true);
        let s = score_frame(&a, &b, &mask);
        let map = ssim_map(&a, &b);
        assert_eq!(s.mse, mse(&a, &b));
        assert_eq!(s.ssim, ssim(&a, &b));
        assert_eq!(s.d_mse, masked_mse(&a, &b, &mask));
        assert!(close(s.d_ssim.unwrap(), map[100..110].iter().sum::<f64>() / 10.0, 1e-15));
        assert_eq!(s.disocclusion_pixels, 10);
        let none = score_frame(&a, &b, &[false; 600]);
        assert_eq!((none.d_mse, none.d_ssim, none.disocclusion_pixels), (None, None, 0));
    }

    // --- temporal consistency -------------------------------------------------------------

    const W: usize = 40;
    const H: usize = 40;
    /// Frames 5..=11; predicted at 6, 8, 10.
    const FRAMES: usize = 7;

    fn square_mask(cx: isize, cy: isize, half: isize) -> Vec<bool> {
        (0..H * W)
            .map(|i| {
                let (u, v) = ((i % W) as isize, (i / W) as isize);
                (u - cx).abs() <= half && (v - cy).abs() <= half
            })
            .collect()
    }

    /// Owns the data of a synthetic sequence: camera at `x = shift_x[t]` (world units), everything
    /// at depth 10, so that a world point moves by `-10 * shift_x[t]` pixels (fx = 100).
    struct Synthetic {
        k: Intrinsics,
        poses: Vec<WorldToCamera>,
        gt: Vec<RgbImage>,
        pred: Vec<Option<RgbImage>>,
        masks: Vec<Option<Vec<bool>>>,
        depth: DepthMap,
        known: Vec<bool>,
    }

    impl Synthetic {
        /// A 3x3 disocclusion around (20, 20) in the first predicted frame, moving with the camera.
        fn new(shift_x: [f64; FRAMES], pred_value: f32, gt_value: f32) -> Self {
            let k = Intrinsics::new(100.0, 100.0, 20.0, 20.0);
            let poses =
                shift_x.iter().map(|&x| WorldToCamera(DMat4::from_translation(DVec3::new(-x, 0.0, 0.0)))).collect();
            let gt = vec![RgbImage::filled(W, H, [gt_value; 3]); FRAMES];
            let predicted = |t: usize| t % 2 == 1;
            let pred = (0..FRAMES).map(|t| predicted(t).then(|| RgbImage::filled(W, H, [pred_value; 3]))).collect();
            let masks = (0..FRAMES)
                .map(|t| {
                    let moved = -10.0 * (shift_x[t] - shift_x[1]);
                    predicted(t).then(|| square_mask(20 + moved.round() as isize, 20, 1))
                })
                .collect();
            let known = square_mask(20, 20, 1).iter().map(|&d| !d).collect();
            Self { k, poses, gt, pred, masks, depth: DepthMap::filled(W, H, [10.0]), known }
        }

        fn seq(&self) -> TcSequence<'_> {
            TcSequence {
                intrinsics: &self.k,
                poses: &self.poses,
                ground_truth: &self.gt,
                predictions: &self.pred,
                disocclusions: &self.masks,
                anchor_depth: &self.depth,
                anchor_known: &self.known,
            }
        }
    }

    #[test]
    fn tc_of_a_constant_error_is_12_e2_over_49() {
        let s = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        let v = tc_track_variances(&s.seq());
        // 16 anchors around the 3x3 square, each reaching all 9 of its pixels.
        assert_eq!(v.len(), 16 * 9);
        let e: f64 = 63.75;
        for x in v {
            assert!(close(x, 12.0 * e * e / 49.0, 1e-9), "{x}");
        }
    }

    #[test]
    fn tc_drops_tracks_that_leave_the_disocclusion() {
        let mut s = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        // Frame 10 (index 5) loses one corner of the square: the 16 tracks through it go.
        s.masks[5].as_mut().unwrap()[21 * W + 21] = false;
        assert_eq!(tc_track_variances(&s.seq()).len(), 16 * 9 - 16);
    }

    #[test]
    fn tc_follows_a_moving_camera() {
        // The camera moves 0.2 units right per frame: the scene moves 2 px left per frame.
        let shifts = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2];
        let s = Synthetic::new(shifts, 0.5, 0.25);
        assert_eq!(tc_track_variances(&s.seq()).len(), 16 * 9);
        // A mask that stays put is left behind by the tracks from frame 8 on.
        let mut still = Synthetic::new(shifts, 0.5, 0.25);
        still.masks = (0..FRAMES).map(|t| (t % 2 == 1).then(|| square_mask(20, 20, 1))).collect();
        assert!(tc_track_variances(&still.seq()).is_empty());
        // Far enough that every track leaves the frame (a 40 px shift) in the last frame.
        let mut out = shifts;
        out[6] = 4.0;
        assert!(tc_track_variances(&Synthetic::new(out, 0.5, 0.25).seq()).is_empty());
    }

    #[test]
    fn tc_drops_tracks_that_land_one_pixel_past_the_last_column_or_row() {
        // The disocclusion covers x and y 19..=21. In the last frame (ground truth, so no mask to
        // stay in) the scene moves by 19 px right or down: the tracks through x (or y) = 21 land
        // on 40, one past the last pixel, and must go; the other two thirds land inside.
        let past = (W - 21) as f64 / 10.0;
        let mut right = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        right.poses[6] = WorldToCamera(DMat4::from_translation(DVec3::new(past, 0.0, 0.0)));
        assert_eq!(tc_track_variances(&right.seq()).len(), 16 * 6);
        let mut down = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        down.poses[6] = WorldToCamera(DMat4::from_translation(DVec3::new(0.0, (H - 21) as f64 / 10.0, 0.0)));
        assert_eq!(tc_track_variances(&down.seq()).len(), 16 * 6);
        // One pixel less and every track stays in the frame.
        let mut inside = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        inside.poses[6] = WorldToCamera(DMat4::from_translation(DVec3::new(past - 0.1, 0.0, 0.0)));
        assert_eq!(tc_track_variances(&inside.seq()).len(), 16 * 9);
    }

    #[test]
    fn tc_skips_points_behind_a_camera() {
        let mut s = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        // Frame 11 looks the other way (180 degrees about y): every point is behind it.
        s.poses[6] = WorldToCamera(DMat4::from_rotation_y(std::f64::consts::PI));
        assert!(tc_track_variances(&s.seq()).is_empty());
    }

    #[test]
    fn tc_has_no_tracks_without_disocclusions_or_predictions() {
        let mut s = Synthetic::new([0.0; FRAMES], 0.5, 0.25);
        s.masks = (0..FRAMES).map(|t| (t % 2 == 1).then(|| vec![false; W * H])).collect();
        s.known = vec![true; W * H];
        assert!(tc_track_variances(&s.seq()).is_empty());
        s.pred = vec![None; FRAMES];
        s.masks = vec![None; FRAMES];
        assert!(tc_track_variances(&s.seq()).is_empty());
    }

    #[test]
    fn tc_of_a_perfect_prediction_is_zero() {
        let s = Synthetic::new([0.0; FRAMES], 0.5, 0.5);
        let v = tc_track_variances(&s.seq());
        assert_eq!(v.len(), 144);
        assert!(v.iter().all(|&x| x == 0.0));
    }

    #[test]
    fn population_variance_does_not_cancel_around_a_large_mean() {
        // Written as sum(v^2) - n mean^2 (or any form that multiplies by v + mean), the rounding of
        // the mean, about 1e-7 here, is multiplied by 2e9: 79.7 instead of 2/9.
        let v = population_variance(&[1e9, 1e9 + 1.0, 1e9 + 1.0]);
        assert!((v - 2.0 / 9.0).abs() < 1e-6, "{v}");
    }

    #[test]
    fn metrics_refuse_images_of_different_sizes() {
        let (a, b) = (RgbImage::filled(4, 3, [0.5; 3]), RgbImage::filled(3, 4, [0.5; 3]));
        for metric in [
            |a: &RgbImage, b: &RgbImage| {
                let _ = mse(a, b);
            },
            |a: &RgbImage, b: &RgbImage| {
                let _ = masked_mse(a, b, &[true; 12]);
            },
            |a: &RgbImage, b: &RgbImage| {
                let _ = ssim_map(a, b);
            },
        ] {
            let refused = std::panic::catch_unwind(|| metric(&a, &b)).expect_err("4x3 against 3x4 was scored");
            let message = refused.downcast_ref::<String>().expect("a formatted message");
            assert!(message.contains("image sizes differ: 4x3 vs 3x4"), "{message}");
        }
    }
}
