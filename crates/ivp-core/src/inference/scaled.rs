//! The network at a coarser scale than the frame: [`Scale`] and [`NetworkFrame`] (ALGORITHMS.md
//! §6.7; the prior at that scale is `prior::scaled_target_prior`, the shrinking `geometry::shrink`).
//!
//! The same head motion opens holes `k` times wider in a frame `k` times larger, while the
//! network is trained on frames of about 320x240. Run on a 1080p frame directly, it must point
//! farther than it ever learned; run on the frame shrunk by an integer factor `s`, it sees holes
//! of the widths it knows, and costs `s^2` times less. Its vectors, scaled back by `s`, point
//! each block of `s x s` hole pixels to a block of known pixels; the iterative infilling then
//! reads colour and depth at full resolution, so texture keeps its detail.

use std::borrow::Cow;

use crate::geometry::shrink::{blocks_with, is_nonzero, shrink_depth_in, shrink_vectors_in, vector_block_mean};
use crate::geometry::{DepthMap, Image, Rect, VectorField};
use crate::prior::ScaledPrior;

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

/// The factor by which frames are shrunk before the temporal prior is measured on them
/// (ALGORITHMS.md §6.7).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PriorScale {
    #[default]
    /// Twice the network's factor where the network sees a shrunk frame (4 at 1080p), else the
    /// network's factor.
    Auto,
    /// Shrink by this factor (1: the prior is measured on the frames as they are).
    Factor(usize),
}

impl PriorScale {
    /// The factor for a frame that the network sees shrunk by `network_factor`: at least 1.
    ///
    /// Why twice: at 1080p the prior measured on frames shrunk by 4 (270 rows, about the 240 of
    /// the recipe's training frames) scored as well as at 2 on the Blender clips and better on
    /// generated ones, for every seed of the recipe, and takes a third of the time
    /// (results/recipe-hd/prior-scale).
    pub fn factor(self, network_factor: usize) -> usize {
        match self {
            PriorScale::Factor(s) => s.max(1),
            PriorScale::Auto if network_factor >= 2 => 2 * network_factor,
            PriorScale::Auto => network_factor.max(1),
        }
    }
}

impl std::str::FromStr for PriorScale {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.parse::<Scale>() {
            Ok(Scale::Auto) => Ok(PriorScale::Auto),
            Ok(Scale::Factor(factor)) => Ok(PriorScale::Factor(factor)),
            Err(_) => Err(format!("the prior's scale must be `auto` or a factor from 1 to 16, not `{s}`")),
        }
    }
}

impl std::fmt::Display for PriorScale {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PriorScale::Auto => f.write_str("auto"),
            PriorScale::Factor(s) => write!(f, "{s}"),
        }
    }
}

/// The inputs of the iterative infilling (prior, depth, holes: full size) as the network sees
/// them: shrunk by `factor` (blocks of `factor x factor` pixels), one window at a time, so that
/// sparse inference shrinks only what its tiles read.
///
/// Shrinking, for each block:
/// - a hole if any of its pixels is one (so every hole pixel has a coarse prediction);
/// - depth: as [`shrink_depth`] says (0 for a hole block, as the network expects);
/// - prior: the mean of its non-zero full-size vectors divided by `factor` (0 for a hole block).
///   A prior kept at this factor, or at a multiple of it (the prior's own scale, [`PriorScale`]),
///   already holds that for every block where nothing was set since (see [`ScaledPrior`]), so
///   only the blocks where the infilling set pixels are shrunk.
///
/// Growing ([`NetworkFrame::write_vectors`]): each hole pixel takes `factor` times the vector of
/// its block. At factor 1 windows are plain crops.
pub struct NetworkFrame<'a> {
    prior: &'a ScaledPrior,
    /// The full-size prior, for a prior kept at a factor that is not a multiple of this frame's.
    full_prior: Option<Cow<'a, VectorField>>,
    /// The blocks (row-major indices at the network's resolution) holding pixels set in `prior`.
    blocks_set: Vec<usize>,
    depth: &'a DepthMap,
    holes: &'a [bool],
    factor: usize,
    /// The holes at the network's resolution.
    network_holes: Cow<'a, [bool]>,
    width: usize,
    height: usize,
}

impl<'a> NetworkFrame<'a> {
    /// `holes` is row-major, `true` = a pixel to predict; all three are of one size.
    pub fn new(prior: &'a ScaledPrior, depth: &'a DepthMap, holes: &'a [bool], factor: usize) -> Self {
        let s = factor.max(1);
        let (w, h) = (depth.width(), depth.height());
        let full_size = (prior.width(), prior.height()) == (w, h);
        assert!(full_size && holes.len() == w * h, "the prior, depth and holes differ in size");
        let network_holes = if s == 1 { Cow::Borrowed(holes) } else { Cow::Owned(blocks_with(w, h, s, holes, true)) };
        let full_prior = match prior.factor() {
            f if f % s == 0 => None,
            1 => Some(Cow::Borrowed(prior.coarse())),
            _ => Some(Cow::Owned(prior.to_full())),
        };
        let (width, height) = (w.div_ceil(s), h.div_ceil(s));
        let mut blocks_set: Vec<usize> = prior.set_pixels().map(|i| (i / w / s) * width + i % w / s).collect();
        blocks_set.sort_unstable();
        blocks_set.dedup();
        Self { prior, full_prior, blocks_set, depth, holes, factor: s, network_holes, width, height }
    }

    /// The frame the network sees, in its pixels.
    pub fn whole(&self) -> Rect {
        Rect::whole(self.width, self.height)
    }

    /// The pixels to predict at the network's resolution, row-major.
    pub fn holes(&self) -> &[bool] {
        &self.network_holes
    }

    /// The prior and the depth the network reads in `window` (its pixels).
    pub fn window(&self, window: Rect) -> (VectorField, DepthMap) {
        let (s, r) = (self.factor, window);
        let mut prior = self.prior_in(window);
        if s == 1 {
            return (prior, self.depth.crop(r.x, r.y, r.width, r.height));
        }
        let mut depth = shrink_depth_in(self.depth, s, window);
        // The network saw no depth and no prior on holes in training.
        for v in 0..r.height {
            let holes = &self.network_holes[(r.y + v) * self.width + r.x..][..r.width];
            for (u, _) in holes.iter().enumerate().filter(|(_, &hole)| hole) {
                depth.set(u, v, [0.0]);
                prior.set(u, v, [0.0, 0.0]);
            }
        }
        (prior, depth)
    }

    /// The prior in `window`, before the holes are cleared.
    fn prior_in(&self, r: Rect) -> VectorField {
        let s = self.factor;
        match &self.full_prior {
            Some(full) if s == 1 => full.crop(r.x, r.y, r.width, r.height),
            Some(full) => shrink_vectors_in(full, s, r),
            None => {
                // Each of this frame's blocks lies in one of the prior's, whose full-size pixels
                // all read `factor` times its vector: shrunk by `s`, `factor / s` times it.
                let (coarse, ratio) = (self.prior.coarse(), self.prior.factor() / s);
                let mut prior = match ratio {
                    1 => coarse.crop(r.x, r.y, r.width, r.height),
                    _ => Image::from_fn(r.width, r.height, |u, v| {
                        coarse.get((r.x + u) / ratio, (r.y + v) / ratio).map(|x| x * ratio as f32)
                    }),
                };
                for &block in &self.blocks_set {
                    let (cu, cv) = (block % self.width, block / self.width);
                    if (r.x..r.x + r.width).contains(&cu) && (r.y..r.y + r.height).contains(&cv) {
                        prior.set(cu - r.x, cv - r.y, self.shrunk_block_prior(cu, cv));
                    }
                }
                prior
            }
        }
    }

    /// The full-size prior of block `(cu, cv)` shrunk as [`shrink_vectors_in`] does it (its rule,
    /// the same sums in the same order).
    fn shrunk_block_prior(&self, cu: usize, cv: usize) -> [f32; 2] {
        let (s, w, h) = (self.factor, self.depth.width(), self.depth.height());
        let (mut sums, mut n) = ([0f64; 2], 0u32);
        for v in cv * s..((cv + 1) * s).min(h) {
            for u in cu * s..((cu + 1) * s).min(w) {
                let [x, y] = self.prior.at(u, v);
                if is_nonzero([x, y]) {
                    (sums, n) = ([sums[0] + x as f64, sums[1] + y as f64], n + 1);
                }
            }
        }
        vector_block_mean(sums, n, s)
    }

    /// The network's hole mask in `window`: 1 at the pixels to predict, else 0.
    pub fn mask(&self, window: Rect) -> DepthMap {
        let r = window;
        Image::from_fn(r.width, r.height, |u, v| {
            [f32::from(u8::from(self.network_holes[(r.y + v) * self.width + r.x + u]))]
        })
    }

    /// Writes the vectors of `core` (the network's pixels; `vector_at` takes coordinates within
    /// it) into the full-size `out` at the pixels to predict: each takes `factor` times its
    /// block's vector. Returns how many of the pixels written got a NaN or infinite vector.
    pub fn write_vectors(
        &self,
        core: Rect,
        vector_at: impl Fn(usize, usize) -> [f32; 2],
        out: &mut VectorField,
    ) -> usize {
        let (s, w, h) = (self.factor, self.depth.width(), self.depth.height());
        let grown = s as f32;
        let field = out.pixels_mut();
        let mut non_finite = 0;
        for cv in core.y..core.y + core.height {
            for cu in core.x..core.x + core.width {
                if !self.network_holes[cv * self.width + cu] {
                    continue;
                }
                let [x, y] = vector_at(cu - core.x, cv - core.y);
                let vector = [x * grown, y * grown];
                let finite = vector.iter().all(|c| c.is_finite());
                for v in cv * s..((cv + 1) * s).min(h) {
                    for u in cu * s..((cu + 1) * s).min(w) {
                        if self.holes[v * w + u] {
                            field[v * w + u] = vector;
                            non_finite += usize::from(!finite);
                        }
                    }
                }
            }
        }
        non_finite
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let prior = ScaledPrior::full_size(prior);
        let frame = NetworkFrame::new(&prior, &depth, &holes, 2);
        assert_eq!(frame.whole(), Rect::whole(3, 2));
        assert_eq!(frame.holes(), [false, true, false, false, false, false]);
        let (coarse_prior, coarse_depth) = frame.window(frame.whole());
        // Block (0, 0): depths 1, 2, 1, 2; prior (4, -2) on its left column only, halved.
        assert_eq!(coarse_depth.get(0, 0), [1.5]);
        assert_eq!(coarse_prior.get(0, 0), [2.0, -1.0]);
        // The hole block reads as a hole: depth 0, no prior. The partial corner block: depth 5.
        assert_eq!((coarse_depth.get(1, 0), coarse_prior.get(1, 0)), ([0.0], [0.0, 0.0]));
        assert_eq!(coarse_depth.get(2, 1), [5.0]);
        assert_eq!(frame.mask(frame.whole()).pixels(), [[0.0], [1.0], [0.0], [0.0], [0.0], [0.0]]);
        let mut vectors = VectorField::zeros(w, h);
        assert_eq!(frame.write_vectors(frame.whole(), |_, _| [1.5, -0.5], &mut vectors), 0);
        for v in 0..h {
            for u in 0..w {
                let expected = if hole(u, v) { [3.0, -1.0] } else { [0.0, 0.0] };
                assert_eq!(vectors.get(u, v), expected, "pixel ({u}, {v})");
            }
        }
        // A non-finite vector is counted once per pixel it is written to.
        let mut vectors = VectorField::zeros(w, h);
        assert_eq!(frame.write_vectors(frame.whole(), |_, _| [f32::NAN, 0.0], &mut vectors), 1);
    }

    /// Sparse inference reads windows of the shrunk frame: each must be the part of the whole.
    #[test]
    fn a_window_is_that_part_of_the_whole_shrunk_frame() {
        let (w, h) = (41, 29);
        let holes: Vec<bool> = (0..w * h).map(|i| (i * 7919) % 23 == 0).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| match (u * 3 + v) % 11 {
            0 => [f32::INFINITY],
            1 => [f32::NAN],
            k => [if holes[v * w + u] { 0.0 } else { 0.5 + k as f32 }],
        });
        let prior =
            VectorField::from_fn(
                w,
                h,
                |u, v| if (u + v) % 3 == 0 { [0.0; 2] } else { [u as f32 - 9.0, 2.0 - v as f32] },
            );
        let prior = ScaledPrior::full_size(prior);
        for s in [1, 2, 3, 5] {
            let frame = NetworkFrame::new(&prior, &depth, &holes, s);
            let whole = frame.whole();
            let (all_prior, all_depth) = frame.window(whole);
            let all_mask = frame.mask(whole);
            for r in [
                whole,
                Rect { x: 1, y: 2, width: 3, height: 4 },
                Rect { x: whole.width - 2, y: whole.height - 1, width: 2, height: 1 },
            ] {
                let (prior_r, depth_r) = frame.window(r);
                assert_eq!(prior_r, all_prior.crop(r.x, r.y, r.width, r.height), "factor {s}, {r:?}");
                let same = |a: f32, b: f32| a == b || (a.is_nan() && b.is_nan());
                let crop = all_depth.crop(r.x, r.y, r.width, r.height);
                assert!(depth_r.pixels().iter().zip(crop.pixels()).all(|(a, b)| same(a[0], b[0])), "factor {s}, {r:?}");
                assert_eq!(frame.mask(r), all_mask.crop(r.x, r.y, r.width, r.height));
            }
        }
    }

    /// A prior kept at the network's factor, or at a multiple of it, is read without growing it:
    /// every window, with pixels set in some blocks, must be what the same prior at full size
    /// gives: to the bit at factors that are powers of 2 (growing and shrinking by them is exact),
    /// else within rounding (the kept value is the one measured; the grown one was rounded once
    /// more). A prior at another factor (3 for a frame at 2) is grown first.
    #[test]
    fn a_prior_kept_at_a_multiple_of_the_factor_reads_as_its_full_size_form() {
        let (w, h) = (41, 29);
        let holes: Vec<bool> = (0..w * h).map(|i| (i * 7919) % 23 == 0).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| [if holes[v * w + u] { 0.0 } else { 1.0 + (u % 5) as f32 }]);
        for (prior_factor, s) in
            [(2, 2), (3, 3), (4, 4), (5, 5), (2, 1), (4, 1), (4, 2), (8, 2), (6, 3), (6, 2), (3, 2)]
        {
            let coarse = VectorField::from_fn(w.div_ceil(prior_factor), h.div_ceil(prior_factor), |u, v| {
                match (u + 2 * v) % 4 {
                    0 => [0.0, 0.0],
                    1 => [0.0, 1.25],
                    _ => [u as f32 * 0.7 - 3.0, 1.5 - v as f32 * 0.3],
                }
            });
            let mut scaled = ScaledPrior::scaled(coarse, prior_factor, w, h);
            // Pixels set in a few blocks (as the infilling sets the pixels it fills), one of them
            // back to zero.
            for (i, vector) in
                [(0, [2.5, -1.0]), (w + 1, [0.0, 0.0]), (5 * w + 7, [-4.0, 3.0]), (w * h - 1, [1.0, 1.0])]
            {
                scaled.set(i, vector);
            }
            let full = ScaledPrior::full_size(scaled.to_full());
            let (kept, grown) =
                (NetworkFrame::new(&scaled, &depth, &holes, s), NetworkFrame::new(&full, &depth, &holes, s));
            let whole = kept.whole();
            let what = format!("prior at {prior_factor}, frame at {s}");
            for r in [whole, Rect { x: 1, y: 2, width: 3, height: 4 }, Rect { x: 0, y: 0, width: 2, height: 2 }] {
                let (kept, grown) = (kept.window(r).0, grown.window(r).0);
                if s.is_power_of_two() && prior_factor.is_power_of_two() {
                    assert_eq!(kept, grown, "{what}, {r:?}");
                }
                let close = |a: f32, b: f32| (a - b).abs() <= 1e-6 * a.abs().max(1.0);
                let pairs = kept.pixels().iter().flatten().zip(grown.pixels().iter().flatten());
                assert!(pairs.into_iter().all(|(&a, &b)| close(a, b)), "{what}, {r:?}");
                // Not all zero: the whole frame holds measured vectors.
                assert!(r != whole || kept.pixels().iter().any(|&v| is_nonzero(v)), "{what}");
            }
        }
    }

    #[test]
    fn the_prior_is_shrunk_twice_as_much_as_a_shrunk_frame_by_default() {
        assert_eq!(PriorScale::Auto.factor(1), 1);
        assert_eq!(PriorScale::Auto.factor(2), 4);
        assert_eq!(PriorScale::Auto.factor(3), 6);
        assert_eq!(PriorScale::Factor(2).factor(1), 2);
        assert_eq!(PriorScale::Factor(0).factor(2), 1);
        assert_eq!("auto".parse::<PriorScale>(), Ok(PriorScale::Auto));
        assert_eq!("3".parse::<PriorScale>(), Ok(PriorScale::Factor(3)));
        assert_eq!(PriorScale::Factor(3).to_string(), "3");
        assert!("17".parse::<PriorScale>().unwrap_err().contains("prior's scale"));
    }

    #[test]
    fn factor_one_reads_the_frame_as_it_is() {
        let (w, h) = (4, 4);
        let holes: Vec<bool> = (0..w * h).map(|i| i == 5).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| [1.0 + (u + v) as f32]);
        let prior = VectorField::from_fn(w, h, |u, v| [u as f32, v as f32]);
        let scaled = ScaledPrior::full_size(prior.clone());
        let frame = NetworkFrame::new(&scaled, &depth, &holes, 1);
        assert_eq!(frame.holes(), &holes[..]);
        assert_eq!(frame.window(frame.whole()), (prior, depth.clone()));
        let mut vectors = VectorField::zeros(w, h);
        frame.write_vectors(
            Rect { x: 1, y: 1, width: 2, height: 2 },
            |u, v| [u as f32 + 1.0, v as f32 + 1.0],
            &mut vectors,
        );
        assert_eq!(vectors.get(1, 1), [1.0, 1.0]);
        assert!(vectors.pixels().iter().enumerate().all(|(i, v)| i == 5 || *v == [0.0, 0.0]));
    }
}
