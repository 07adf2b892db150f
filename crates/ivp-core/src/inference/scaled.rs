//! The network and the temporal prior at a coarser scale than the frame: [`ScaledPredictor`] and
//! [`shrunk_temporal_prior`] (ALGORITHMS.md §6.7).
//!
//! The same head motion opens holes `k` times wider in a frame `k` times larger, while the
//! network is trained on frames of about 320x240. Run on a 1080p frame directly, it must point
//! farther than it ever learned; run on the frame shrunk by an integer factor `s`, it sees holes
//! of the widths it knows, and costs `s^2` times less. Its vectors, scaled back by `s`, point
//! each block of `s x s` hole pixels to a block of known pixels; the iterative infilling then
//! reads colour and depth at full resolution, so texture keeps its detail.

use rayon::prelude::*;

use crate::geometry::image::is_valid_depth;
use crate::geometry::{DepthMap, FrameView, Image, Intrinsics, RgbImage, VectorField};
use crate::infill::iterative::VectorPredictor;
use crate::infill::{InfillContext, InfillError};
use crate::prior::target_prior;

/// The factor by which frames are shrunk before the network sees them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Scale {
    #[default]
    /// Shrink frames towards [`Scale::REFERENCE_HEIGHT`] by the nearest integer factor.
    Auto,
    /// Shrink by this factor (1: the network sees the frame as it is).
    Factor(usize),
}

impl Scale {
    /// Frames are shrunk to about this height. The recipe trains on 320x240 frames; at 1080p,
    /// factor 2 scored best on average over three seeds of the recipe on the Blender clip and
    /// close to best on generated clips, where factor 3 lost 10-25% for two of the seeds
    /// (PERFORMANCE.md, "Scaled inference").
    pub const REFERENCE_HEIGHT: usize = 540;

    /// The factor for a frame `height` pixels tall: at least 1.
    pub fn factor(self, height: usize) -> usize {
        match self {
            Scale::Factor(s) => s.max(1),
            Scale::Auto => ((height as f64 / Self::REFERENCE_HEIGHT as f64).round() as usize).max(1),
        }
    }
}

impl std::str::FromStr for Scale {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(Scale::Auto);
        }
        match s.parse::<usize>() {
            Ok(factor @ 1..=16) => Ok(Scale::Factor(factor)),
            _ => Err(format!("scale must be `auto` or a factor from 1 to 16, not `{s}`")),
        }
    }
}

impl std::fmt::Display for Scale {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Scale::Auto => f.write_str("auto"),
            Scale::Factor(s) => write!(f, "{s}"),
        }
    }
}

/// A [`VectorPredictor`] that runs `inner` on the frame shrunk by `factor` (blocks of
/// `factor x factor` pixels) and scales its vectors back.
///
/// Shrinking, for each block:
/// - a hole if any of its pixels is one (so every hole pixel has a coarse prediction);
/// - depth: as [`shrink_depth`] says (0 for a hole block, as the network expects);
/// - prior: the mean of its non-zero vectors divided by `factor` (0 for a hole block).
///
/// Growing: each hole pixel takes `factor` times the vector of its block.
pub struct ScaledPredictor<P> {
    inner: P,
    factor: usize,
}

impl<P: VectorPredictor> ScaledPredictor<P> {
    pub fn new(inner: P, factor: usize) -> Self {
        Self { inner, factor: factor.max(1) }
    }

    pub fn inner(&self) -> &P {
        &self.inner
    }
}

impl<P: VectorPredictor> VectorPredictor for ScaledPredictor<P> {
    fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
        let s = self.factor;
        if s == 1 {
            return self.inner.predict(prior, depth, holes);
        }
        let (w, h) = (depth.width(), depth.height());
        let coarse_holes = blocks_with(w, h, s, holes, true);
        // The network saw no depth and no prior on holes in training.
        let mut coarse_depth = shrink_depth(depth, s);
        let mut coarse_prior = shrink_vectors(prior, s);
        for ((hole, z), p) in coarse_holes.iter().zip(coarse_depth.pixels_mut()).zip(coarse_prior.pixels_mut()) {
            if *hole {
                (*z, *p) = ([0.0], [0.0, 0.0]);
            }
        }
        let coarse = self.inner.predict(&coarse_prior, &coarse_depth, &coarse_holes)?;
        Ok(grow_vectors(&coarse, s, w, h, holes))
    }
}

/// The temporal prior of `ctx`'s target (ALGORITHMS.md §6.2) computed on the frames shrunk by
/// `factor`, as a full-size field: each known pixel takes `factor` times the prior of its block,
/// holes take 0. `None` without frame `n - 2`.
///
/// Why: the prior's warps and searches cost as much as the rest of a 1080p frame together, while
/// the network that reads it sees the frame shrunk anyway; measured on the shrunk frames, the
/// prior also looks like the ones the network was trained with (frames of a few hundred rows).
pub fn shrunk_temporal_prior(ctx: &InfillContext<'_>, factor: usize) -> Option<VectorField> {
    let before_last = ctx.before_last.as_ref()?;
    let s = factor.max(1);
    if s == 1 {
        return ctx.temporal_prior().map(|p| p.prior);
    }
    let shrink = |view: &FrameView<'_>| (shrink_image(view.image, s), shrink_depth(view.depth, s));
    let ((image_b, depth_b), (image_n, depth_n)) = rayon::join(|| shrink(before_last), || shrink(&ctx.last));
    let view_b = FrameView { image: &image_b, depth: &depth_b, pose: before_last.pose };
    let view_n = FrameView { image: &image_n, depth: &depth_n, pose: ctx.last.pose };
    let holes = &ctx.warped.holes;
    let (w, h) = (holes.width(), holes.height());
    let known = holes.known();
    // A block is known when all its pixels are (as in ScaledPredictor, where any hole makes a hole).
    let coarse_known: Vec<bool> = blocks_with(w, h, s, &known, false).into_iter().map(|hole| !hole).collect();
    let k = shrink_intrinsics(ctx.intrinsics, s);
    let coarse = target_prior(&view_b, &view_n, ctx.target_pose, &k, &coarse_known).prior;
    Some(grow_vectors(&coarse, s, w, h, &known))
}

/// A `w x h` field in which each pixel marked in `at` takes `s` times the vector of its block of
/// `coarse` (vectors are in pixels, so they grow with the frame); the others are 0.
fn grow_vectors(coarse: &VectorField, s: usize, w: usize, h: usize, at: &[bool]) -> VectorField {
    let grown = s as f32;
    let mut field = VectorField::zeros(w, h);
    field.pixels_mut().par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
        let marks = row.chunks_mut(s).zip(at[v * w..(v + 1) * w].chunks(s));
        for ((out, at), &[x, y]) in marks.zip(coarse.row(v / s)) {
            for (out, _) in out.iter_mut().zip(at).filter(|(_, &at)| at) {
                *out = [x * grown, y * grown];
            }
        }
    });
    debug_assert!(h == 0 || coarse.height() == h.div_ceil(s));
    field
}

/// The intrinsics of a frame shrunk by blocks of `s`: pixel centres at integers, so block `c`
/// is centred on full-size coordinate `c s + (s - 1) / 2`.
pub fn shrink_intrinsics(k: &Intrinsics, s: usize) -> Intrinsics {
    let (s, half) = (s as f64, (s as f64 - 1.0) / 2.0);
    Intrinsics::new(k.fx / s, k.fy / s, (k.cx - half) / s, (k.cy - half) / s)
}

/// Each block of `s x s` pixels (partial at the right and bottom) becomes its mean colour.
pub fn shrink_image(image: &RgbImage, s: usize) -> RgbImage {
    shrink_blocks(
        image,
        s,
        |(sum, n): &mut ([f64; 3], usize), p| {
            (0..3).for_each(|c| sum[c] += p[c] as f64);
            *n += 1;
        },
        |(sum, n)| sum.map(|x| (x / n as f64) as f32),
    )
}

/// Each block of `s x s` depths becomes the mean of its valid depths; a block without any is
/// `+inf` when it holds sky (`+inf`) and 0 (missing) otherwise.
pub fn shrink_depth(depth: &DepthMap, s: usize) -> DepthMap {
    shrink_blocks(
        depth,
        s,
        |(sum, n, sky): &mut (f64, usize, bool), [z]| {
            if is_valid_depth(z) {
                *sum += z as f64;
                *n += 1;
            }
            *sky |= z == f32::INFINITY;
        },
        |(sum, n, sky)| {
            [if n > 0 {
                (sum / n as f64) as f32
            } else if sky {
                f32::INFINITY
            } else {
                0.0
            }]
        },
    )
}

/// Each block of `s x s` vectors (in pixels) becomes the mean of its non-zero vectors divided by
/// `s`, or 0 when it has none.
fn shrink_vectors(field: &VectorField, s: usize) -> VectorField {
    shrink_blocks(
        field,
        s,
        |(sum, n): &mut ([f64; 2], usize), [x, y]| {
            if x != 0.0 || y != 0.0 {
                *sum = [sum[0] + x as f64, sum[1] + y as f64];
                *n += 1;
            }
        },
        |(sum, n)| if n == 0 { [0.0, 0.0] } else { sum.map(|x| (x / (n * s) as f64) as f32) },
    )
}

/// For each block of `s x s` pixels of a `w x h` frame, whether any of its pixels (row-major
/// in `mask`) is `value`.
fn blocks_with(w: usize, h: usize, s: usize, mask: &[bool], value: bool) -> Vec<bool> {
    let cw = w.div_ceil(s);
    let mut out = vec![false; cw * h.div_ceil(s)];
    out.par_chunks_mut(cw.max(1)).enumerate().for_each(|(cv, blocks)| {
        for row in mask[cv * s * w..((cv + 1) * s).min(h) * w].chunks(w) {
            for (block, pixels) in blocks.iter_mut().zip(row.chunks(s)) {
                *block |= pixels.contains(&value);
            }
        }
    });
    out
}

/// `image` shrunk by blocks of `s x s`: each block's pixels are folded into an accumulator by
/// `add`, which `finish` turns into the block's value. One row of blocks at a time, reading the
/// frame's rows front to back (the frame is tens of megabytes: this stage runs at memory speed).
fn shrink_blocks<const C: usize, A: Default + Clone + Send>(
    image: &Image<C>,
    s: usize,
    add: impl Fn(&mut A, [f32; C]) + Sync,
    finish: impl Fn(A) -> [f32; C] + Sync,
) -> Image<C> {
    let (w, h) = (image.width(), image.height());
    let (cw, ch) = (w.div_ceil(s), h.div_ceil(s));
    let mut out = Image::zeros(cw, ch);
    out.pixels_mut().par_chunks_mut(cw.max(1)).enumerate().for_each(|(cv, cells)| {
        let mut accumulators = vec![A::default(); cw];
        for v in cv * s..((cv + 1) * s).min(h) {
            for (acc, pixels) in accumulators.iter_mut().zip(image.row(v).chunks(s)) {
                pixels.iter().for_each(|&p| add(acc, p));
            }
        }
        for (cell, acc) in cells.iter_mut().zip(accumulators) {
            *cell = finish(acc);
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// Records what it was asked and answers a fixed vector on every hole.
    struct Probe {
        seen: Mutex<Option<(VectorField, DepthMap, Vec<bool>)>>,
        answer: [f32; 2],
    }

    impl VectorPredictor for Probe {
        fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
            *self.seen.lock().unwrap() = Some((prior.clone(), depth.clone(), holes.to_vec()));
            let w = depth.width();
            Ok(VectorField::from_fn(w, depth.height(), |u, v| if holes[v * w + u] { self.answer } else { [0.0; 2] }))
        }
    }

    #[test]
    fn auto_scale_shrinks_tall_frames_towards_the_training_height() {
        assert_eq!(Scale::Auto.factor(240), 1);
        assert_eq!(Scale::Auto.factor(100), 1);
        assert_eq!(Scale::Auto.factor(720), 1);
        assert_eq!(Scale::Auto.factor(810), 2);
        assert_eq!(Scale::Auto.factor(1080), 2);
        assert_eq!(Scale::Auto.factor(1440), 3);
        assert_eq!(Scale::Auto.factor(2160), 4);
        assert_eq!(Scale::Factor(3).factor(1080), 3);
        assert_eq!("auto".parse::<Scale>(), Ok(Scale::Auto));
        assert_eq!("4".parse::<Scale>(), Ok(Scale::Factor(4)));
        assert!("0".parse::<Scale>().unwrap_err().contains("from 1 to 16"));
    }

    #[test]
    fn blocks_shrink_and_vectors_grow_by_the_factor() {
        // 5 x 3 pixels at factor 2: 3 x 2 blocks, the last column and row partial.
        let (w, h) = (5, 3);
        let hole = |u: usize, v: usize| u == 2 && v == 0;
        let holes: Vec<bool> = (0..w * h).map(|i| hole(i % w, i / w)).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| [if hole(u, v) { 0.0 } else { 1.0 + u as f32 }]);
        let prior = VectorField::from_fn(w, h, |u, _| if u == 0 { [4.0, -2.0] } else { [0.0; 2] });
        let probe = Probe { seen: Mutex::new(None), answer: [1.5, -0.5] };
        let vectors = ScaledPredictor::new(&probe, 2).predict(&prior, &depth, &holes).unwrap();
        let (coarse_prior, coarse_depth, coarse_holes) = probe.seen.lock().unwrap().take().unwrap();
        assert_eq!((coarse_depth.width(), coarse_depth.height()), (3, 2));
        assert_eq!(coarse_holes, [false, true, false, false, false, false]);
        // Block (0, 0): depths 1, 2, 1, 2; prior (4, -2) on its left column only, halved.
        assert_eq!(coarse_depth.get(0, 0), [1.5]);
        assert_eq!(coarse_prior.get(0, 0), [2.0, -1.0]);
        // The hole block reads as a hole: depth 0, no prior. The partial corner block: depth 5.
        assert_eq!((coarse_depth.get(1, 0), coarse_prior.get(1, 0)), ([0.0], [0.0, 0.0]));
        assert_eq!(coarse_depth.get(2, 1), [5.0]);
        for v in 0..h {
            for u in 0..w {
                let expected = if hole(u, v) { [3.0, -1.0] } else { [0.0, 0.0] };
                assert_eq!(vectors.get(u, v), expected, "pixel ({u}, {v})");
            }
        }
    }

    #[test]
    fn factor_one_passes_through() {
        let (w, h) = (4, 4);
        let holes: Vec<bool> = (0..w * h).map(|i| i == 5).collect();
        let depth = DepthMap::filled(w, h, [2.0]);
        let prior = VectorField::zeros(w, h);
        let probe = Probe { seen: Mutex::new(None), answer: [1.0, 1.0] };
        let vectors = ScaledPredictor::new(&probe, 1).predict(&prior, &depth, &holes).unwrap();
        let (_, seen_depth, seen_holes) = probe.seen.lock().unwrap().take().unwrap();
        assert_eq!((seen_depth, seen_holes), (depth, holes));
        assert_eq!(vectors.get(1, 1), [1.0, 1.0]);
    }

    #[test]
    fn shrunk_intrinsics_project_to_the_block_centres() {
        let k = Intrinsics::new(2100.0, 2000.0, 960.0, 540.0);
        for s in [2usize, 3, 4] {
            let c = shrink_intrinsics(&k, s);
            for (x, y, z) in [(0.3, -0.2, 4.0), (-1.0, 0.5, 2.5)] {
                let (u, v) = (k.fx * x / z + k.cx, k.fy * y / z + k.cy);
                let (cu, cv) = (c.fx * x / z + c.cx, c.fy * y / z + c.cy);
                // Full-size coordinate of coarse coordinate c: c s + (s - 1) / 2.
                let half = (s as f64 - 1.0) / 2.0;
                assert!((cu * s as f64 + half - u).abs() < 1e-9 && (cv * s as f64 + half - v).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn shrinking_averages_colours_and_valid_depths() {
        let image = RgbImage::from_fn(3, 2, |u, v| [u as f32, v as f32, 1.0]);
        let shrunk = shrink_image(&image, 2);
        assert_eq!((shrunk.width(), shrunk.height()), (2, 1));
        assert_eq!(shrunk.get(0, 0), [0.5, 0.5, 1.0]);
        assert_eq!(shrunk.get(1, 0), [2.0, 0.5, 1.0]); // the partial block: one column
                                                       // Valid depths are averaged; invalid ones are left out; sky stays sky, missing stays 0.
        let depth = DepthMap::from_pixels(
            4,
            2,
            vec![[2.0], [f32::NAN], [f32::INFINITY], [0.0], [4.0], [-1.0], [0.0], [f32::INFINITY]],
        );
        let shrunk = shrink_depth(&depth, 2);
        assert_eq!(shrunk.get(0, 0), [3.0]);
        assert_eq!(shrunk.get(1, 0), [f32::INFINITY]);
        let missing = shrink_depth(&DepthMap::from_pixels(2, 1, vec![[0.0], [f32::NAN]]), 2);
        assert_eq!(missing.get(0, 0), [0.0]);
    }

    #[test]
    fn the_shrunk_prior_is_the_plain_one_at_factor_one_and_zero_on_holes() {
        use crate::geometry::{relative_pose, warp_forward, FrameView};
        use crate::test_scene::{intrinsics, render};
        let k = intrinsics();
        let frames: Vec<_> = [0.0, 0.2, 0.3].into_iter().map(render).collect();
        let warped = warp_forward(&frames[1].0, &frames[1].1, &k, &relative_pose(&frames[1].2, &frames[2].2));
        let view = |i: usize| FrameView { image: &frames[i].0, depth: &frames[i].1, pose: &frames[i].2 };
        let ctx = InfillContext {
            intrinsics: &k,
            last: view(1),
            before_last: Some(view(0)),
            target_pose: &frames[2].2,
            warped: &warped,
            ground_truth: None,
        };
        assert_eq!(shrunk_temporal_prior(&ctx, 1), ctx.temporal_prior().map(|p| p.prior));
        let fine = ctx.temporal_prior().unwrap().prior;
        let shrunk = shrunk_temporal_prior(&ctx, 2).unwrap();
        let known = warped.holes.known();
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
    fn a_network_shrunk_to_a_few_pixels_still_fills_every_hole() {
        use crate::nn::model::{IvpNet, ModelConfig, Variant};
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        // 37 x 23 pixels at factor 16: 3 x 2 blocks, one of them holding the whole hole.
        let (w, h) = (37, 23);
        let holes: Vec<bool> = (0..w * h).map(|i| (10..14).contains(&(i % w)) && (5..9).contains(&(i / w))).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| [if holes[v * w + u] { 0.0 } else { 3.0 + u as f32 }]);
        let prior = VectorField::zeros(w, h);
        for factor in [16, 40] {
            let vectors = ScaledPredictor::new(&net, factor).predict(&prior, &depth, &holes).unwrap();
            assert_eq!((vectors.width(), vectors.height()), (w, h));
            for (i, v) in vectors.pixels().iter().enumerate() {
                assert!(v.iter().all(|x| x.is_finite()), "factor {factor}, pixel {i}: {v:?}");
                if !holes[i] {
                    assert_eq!(*v, [0.0, 0.0]);
                }
            }
        }
    }
}
