//! The network and the temporal prior at a coarser scale than the frame: [`NetworkFrame`] and
//! [`shrunk_temporal_prior`] (ALGORITHMS.md §6.7).
//!
//! The same head motion opens holes `k` times wider in a frame `k` times larger, while the
//! network is trained on frames of about 320x240. Run on a 1080p frame directly, it must point
//! farther than it ever learned; run on the frame shrunk by an integer factor `s`, it sees holes
//! of the widths it knows, and costs `s^2` times less. Its vectors, scaled back by `s`, point
//! each block of `s x s` hole pixels to a block of known pixels; the iterative infilling then
//! reads colour and depth at full resolution, so texture keeps its detail.

use std::borrow::Cow;

use rayon::prelude::*;

use crate::geometry::image::is_valid_depth;
use crate::geometry::{
    relative_pose, warp_known, within_reach, DepthMap, FrameView, Image, Intrinsics, Rect, RgbImage, VectorField,
};
use crate::infill::InfillContext;
use crate::prior::{prior_from_last, ScaledPrior, GROUND_TRUTH_REACH};

/// `$body` with `$S` a constant equal to the block size `$s` when it is 2, 3 or 4 (the common
/// factors), else 0, for which the `_by` functions below read `s` itself. With the size known at
/// compile time the loops over a block's pixels unroll and vectorise (shrinking a 1080p depth map
/// took 3.5 ms, now 1.0).
macro_rules! with_block_size {
    ($s:expr, $S:ident => $body:expr) => {
        match $s {
            2 => {
                const $S: usize = 2;
                $body
            }
            3 => {
                const $S: usize = 3;
                $body
            }
            4 => {
                const $S: usize = 4;
                $body
            }
            _ => {
                const $S: usize = 0;
                $body
            }
        }
    };
}

/// The block size of a `_by::<S>` function given `s`. Called again inside parallel closures: a
/// closure reads a captured `s` from memory, a constant it knows.
const fn block_size<const S: usize>(s: usize) -> usize {
    if S == 0 {
        s
    } else {
        S
    }
}

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

/// The inputs of the iterative infilling (prior, depth, holes: full size) as the network sees
/// them: shrunk by `factor` (blocks of `factor x factor` pixels), one window at a time, so that
/// sparse inference shrinks only what its tiles read.
///
/// Shrinking, for each block:
/// - a hole if any of its pixels is one (so every hole pixel has a coarse prediction);
/// - depth: as [`shrink_depth`] says (0 for a hole block, as the network expects);
/// - prior: the mean of its non-zero full-size vectors divided by `factor` (0 for a hole block).
///   A prior kept at this factor already holds that for every block where nothing was set since
///   (see [`ScaledPrior`]), so only the blocks where the infilling set pixels are shrunk.
///
/// Growing ([`NetworkFrame::write_vectors`]): each hole pixel takes `factor` times the vector of
/// its block. At factor 1 windows are plain crops.
pub struct NetworkFrame<'a> {
    prior: &'a ScaledPrior,
    /// The full-size prior, for a prior kept at another factor than this frame's.
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
            f if f == s => None,
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
                let mut prior = self.prior.coarse().crop(r.x, r.y, r.width, r.height);
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

/// The temporal prior of `ctx`'s target (ALGORITHMS.md §6.2) computed on the frames shrunk by
/// `factor`, kept at that scale: as a full-size field, each pixel takes `factor` times the prior
/// of its block, and blocks with a hole take 0. `None` without frame `n - 2`.
///
/// Why: the prior's warps and searches cost as much as the rest of a 1080p frame together, while
/// the network that reads it sees the frame shrunk anyway; measured on the shrunk frames, the
/// prior also looks like the ones the network was trained with (frames of a few hundred rows).
/// Only what the prior reads is shrunk: the depths of frames `n - 2` and `n` (warped whole), and
/// the colours of frame `n` near the holes of the warp `n - 2 -> n` (the fictitious vectors'
/// patches, [`GROUND_TRUTH_REACH`]); frame `n - 2`'s colours are not read at all.
pub fn shrunk_temporal_prior(ctx: &InfillContext<'_>, factor: usize) -> Option<ScaledPrior> {
    let before_last = ctx.before_last.as_ref()?;
    let s = factor.max(1);
    let holes = &ctx.warped.holes;
    let (w, h) = (holes.width(), holes.height());
    let known = holes.known();
    let (depth_b, depth_n) = match s {
        1 => (Cow::Borrowed(before_last.depth), Cow::Borrowed(ctx.last.depth)),
        _ => {
            let (b, n) = rayon::join(|| shrink_depth(before_last.depth, s), || shrink_depth(ctx.last.depth, s));
            (Cow::Owned(b), Cow::Owned(n))
        }
    };
    let k = shrink_intrinsics(ctx.intrinsics, s);
    let known_n = warp_known(&depth_b, &k, &relative_pose(before_last.pose, ctx.last.pose));
    let image_n = match s {
        1 => Cow::Borrowed(ctx.last.image),
        _ => {
            let holes_n: Vec<bool> = known_n.iter().map(|&k| !k).collect();
            let read = within_reach(&holes_n, depth_n.width(), depth_n.height(), GROUND_TRUTH_REACH);
            Cow::Owned(shrink_image_at(ctx.last.image, s, Some(&read)))
        }
    };
    let view_n = FrameView { image: &image_n, depth: &depth_n, pose: ctx.last.pose };
    if s == 1 {
        return Some(ScaledPrior::full_size(prior_from_last(&known_n, &view_n, ctx.target_pose, &k, &known)));
    }
    // A block is known when all its pixels are (as in NetworkFrame, where any hole makes a hole).
    let coarse_known: Vec<bool> = blocks_with(w, h, s, &known, false).into_iter().map(|hole| !hole).collect();
    let coarse = prior_from_last(&known_n, &view_n, ctx.target_pose, &k, &coarse_known);
    Some(ScaledPrior::scaled(coarse, s, w, h))
}

/// The intrinsics of a frame shrunk by blocks of `s`: pixel centres at integers, so block `c`
/// is centred on full-size coordinate `c s + (s - 1) / 2`.
pub fn shrink_intrinsics(k: &Intrinsics, s: usize) -> Intrinsics {
    let (s, half) = (s as f64, (s as f64 - 1.0) / 2.0);
    Intrinsics::new(k.fx / s, k.fy / s, (k.cx - half) / s, (k.cy - half) / s)
}

/// Each block of `s x s` pixels (partial at the right and bottom) becomes its mean colour.
pub fn shrink_image(image: &RgbImage, s: usize) -> RgbImage {
    shrink_image_at(image, s, None)
}

/// [`shrink_image`] at the blocks marked in `at` (row-major, of the shrunk size) only, the others
/// 0; at every block without `at`.
fn shrink_image_at(image: &RgbImage, s: usize, at: Option<&[bool]>) -> RgbImage {
    let rule = BlockRule {
        take: |_| true,
        flag: |_| false,
        finish: |sums: [f64; 3], n, _| sums.map(|x| (x / n as f64) as f32),
    };
    shrink_blocks(image, s, shrunk_whole(image, s), at, rule)
}

/// Each block of `s x s` depths becomes the mean of its valid depths; a block without any is
/// `+inf` when it holds sky (`+inf`) and 0 (missing) otherwise.
pub fn shrink_depth(depth: &DepthMap, s: usize) -> DepthMap {
    shrink_depth_in(depth, s, shrunk_whole(depth, s))
}

/// [`shrink_depth`] in `window` of the shrunk frame.
fn shrink_depth_in(depth: &DepthMap, s: usize, window: Rect) -> DepthMap {
    let rule = BlockRule {
        take: |[z]: [f32; 1]| is_valid_depth(z),
        flag: |[z]: [f32; 1]| z == f32::INFINITY,
        finish: |[sum]: [f64; 1], n, sky| {
            [if n > 0 {
                (sum / n as f64) as f32
            } else if sky {
                f32::INFINITY
            } else {
                0.0
            }]
        },
    };
    shrink_blocks(depth, s, window, None, rule)
}

/// In `window` of the shrunk frame, each block of `s x s` vectors (in pixels) becomes the mean
/// of its non-zero vectors divided by `s`, or 0 when it has none.
fn shrink_vectors_in(field: &VectorField, s: usize, window: Rect) -> VectorField {
    let rule = BlockRule { take: is_nonzero, flag: |_| false, finish: |sums, n, _| vector_block_mean(sums, n, s) };
    shrink_blocks(field, s, window, None, rule)
}

/// Whether a vector counts in its block's mean.
fn is_nonzero([x, y]: [f32; 2]) -> bool {
    x != 0.0 || y != 0.0
}

/// A block of `s x s` vectors whose `n` non-zero ones sum to `sums`, shrunk: their mean divided
/// by `s` (0 without any).
fn vector_block_mean(sums: [f64; 2], n: u32, s: usize) -> [f32; 2] {
    if n == 0 {
        [0.0, 0.0]
    } else {
        sums.map(|x| (x / (n * s as u32) as f64) as f32)
    }
}

/// The whole of `image` shrunk by blocks of `s`, in blocks.
fn shrunk_whole<const C: usize>(image: &Image<C>, s: usize) -> Rect {
    Rect::whole(image.width().div_ceil(s), image.height().div_ceil(s))
}

/// For each block of `s x s` pixels of a `w x h` frame, whether any of its pixels (row-major
/// in `mask`) is `value`.
fn blocks_with(w: usize, h: usize, s: usize, mask: &[bool], value: bool) -> Vec<bool> {
    with_block_size!(s, S => blocks_with_by::<S>(w, h, s, mask, value))
}

/// [`blocks_with`] for blocks of [`block_size`]`::<S>(s)`.
fn blocks_with_by<const S: usize>(w: usize, h: usize, s: usize, mask: &[bool], value: bool) -> Vec<bool> {
    let cw = w.div_ceil(s);
    let mut out = vec![false; cw * h.div_ceil(s)];
    out.par_chunks_mut(cw.max(1)).enumerate().for_each(|(cv, blocks)| {
        let s = block_size::<S>(s);
        for row in mask[cv * s * w..((cv + 1) * s).min(h) * w].chunks(w) {
            let mut pixels = row.chunks_exact(s);
            for (block, pixels) in blocks.iter_mut().zip(&mut pixels) {
                *block |= pixels.contains(&value);
            }
            if !pixels.remainder().is_empty() {
                blocks[cw - 1] |= pixels.remainder().contains(&value);
            }
        }
    });
    out
}

/// Blocks per parallel task of [`shrink_blocks`], at least.
const BLOCKS_PER_TASK: usize = 4096;

/// What [`shrink_blocks`] makes of a block: `finish` of the sums (in f64, in the order of the
/// pixels) of the pixels that `take` takes, how many it took, and whether `flag` holds for any of
/// its pixels.
struct BlockRule<T, F, G> {
    take: T,
    flag: F,
    finish: G,
}

/// `window` (in blocks) of `image` shrunk by blocks of `s x s` as `rule` says, at the blocks
/// marked in `at` (row-major, of the window's size; every block without it), the others 0.
fn shrink_blocks<const C: usize, T, F, G>(
    image: &Image<C>,
    s: usize,
    window: Rect,
    at: Option<&[bool]>,
    rule: BlockRule<T, F, G>,
) -> Image<C>
where
    T: Fn([f32; C]) -> bool + Sync,
    F: Fn([f32; C]) -> bool + Sync,
    G: Fn([f64; C], u32, bool) -> [f32; C] + Sync,
{
    with_block_size!(s, S => shrink_blocks_by::<S, C, T, F, G>(image, s, window, at, &rule))
}

/// [`shrink_blocks`] for blocks of [`block_size`]`::<S>(s)`. One array per kind of sum, so that
/// the loop over a row of blocks runs over several blocks at once (3x faster than over an array
/// of tuples of sums). One row of blocks at a time, reading the frame's rows front to back.
fn shrink_blocks_by<const S: usize, const C: usize, T, F, G>(
    image: &Image<C>,
    s: usize,
    window: Rect,
    at: Option<&[bool]>,
    rule: &BlockRule<T, F, G>,
) -> Image<C>
where
    T: Fn([f32; C]) -> bool + Sync,
    F: Fn([f32; C]) -> bool + Sync,
    G: Fn([f64; C], u32, bool) -> [f32; C] + Sync,
{
    let (w, h, r) = (image.width(), image.height(), window);
    assert!((r.x + r.width) * s < w + s && (r.y + r.height) * s < h + s, "window outside the shrunk frame");
    assert!(at.is_none_or(|at| at.len() == r.area()), "block mask does not match the window");
    let columns = r.x * s..((r.x + r.width) * s).min(w);
    let mut out = Image::zeros(r.width, r.height);
    // Rows of blocks in tasks of a few thousand blocks: a tile's rows are short, and a task per
    // row cost as much as its work.
    let rows_per_task = (BLOCKS_PER_TASK / r.width.max(1)).max(1);
    let rows = out.pixels_mut().par_chunks_mut(r.width.max(1)).enumerate().with_min_len(rows_per_task);
    let buffers = || (vec![[0f64; C]; r.width], vec![0u32; r.width], vec![false; r.width]);
    rows.for_each_init(buffers, |(sums, counts, flagged), (row, cells)| {
        let s = block_size::<S>(s);
        let marks = at.map(|at| &at[row * r.width..][..r.width]);
        if marks.is_some_and(|m| !m.contains(&true)) {
            return;
        }
        sums.fill([0.0; C]);
        counts.fill(0);
        flagged.fill(false);
        let add = |p: [f32; C], sum: &mut [f64; C], count: &mut u32, flagged: &mut bool| {
            // Without a branch: adding 0 leaves a sum as it is.
            let taken = (rule.take)(p);
            sum.iter_mut().zip(p).for_each(|(sum, x)| *sum += if taken { x as f64 } else { 0.0 });
            *count += u32::from(taken);
            *flagged |= (rule.flag)(p);
        };
        for v in (r.y + row) * s..((r.y + row + 1) * s).min(h) {
            let pixels = &image.row(v)[columns.clone()];
            match marks {
                None => {
                    let mut blocks = pixels.chunks_exact(s);
                    let all = sums.iter_mut().zip(counts.iter_mut()).zip(flagged.iter_mut());
                    for (block, ((sum, count), flagged)) in (&mut blocks).zip(all) {
                        block.iter().for_each(|&p| add(p, sum, count, flagged));
                    }
                    // The partial block at the frame's right edge.
                    let last = r.width - 1;
                    for &p in blocks.remainder() {
                        add(p, &mut sums[last], &mut counts[last], &mut flagged[last]);
                    }
                }
                Some(marks) => {
                    for cu in (0..r.width).filter(|&cu| marks[cu]) {
                        for &p in &pixels[cu * s..((cu + 1) * s).min(pixels.len())] {
                            add(p, &mut sums[cu], &mut counts[cu], &mut flagged[cu]);
                        }
                    }
                }
            }
        }
        for (cu, cell) in cells.iter_mut().enumerate() {
            if marks.is_none_or(|m| m[cu]) {
                *cell = (rule.finish)(sums[cu], counts[cu], flagged[cu]);
            }
        }
    });
    out
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

    /// A prior kept at the network's factor is read without growing it: every window, with
    /// pixels set in some blocks, must be what the same prior at full size gives: to the bit at
    /// factors that are powers of 2 (growing and shrinking by them is exact), else within
    /// rounding (the kept value is the one measured; the grown one was rounded once more).
    #[test]
    fn a_prior_kept_at_the_factor_reads_as_its_full_size_form() {
        let (w, h) = (41, 29);
        let holes: Vec<bool> = (0..w * h).map(|i| (i * 7919) % 23 == 0).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| [if holes[v * w + u] { 0.0 } else { 1.0 + (u % 5) as f32 }]);
        for s in [2, 3, 4, 5] {
            let coarse = VectorField::from_fn(w.div_ceil(s), h.div_ceil(s), |u, v| match (u + 2 * v) % 4 {
                0 => [0.0, 0.0],
                1 => [0.0, 1.25],
                _ => [u as f32 * 0.7 - 3.0, 1.5 - v as f32 * 0.3],
            });
            let mut scaled = ScaledPrior::scaled(coarse, s, w, h);
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
            for r in [whole, Rect { x: 1, y: 2, width: 3, height: 4 }, Rect { x: 0, y: 0, width: 2, height: 2 }] {
                let (kept, grown) = (kept.window(r).0, grown.window(r).0);
                if s.is_power_of_two() {
                    assert_eq!(kept, grown, "factor {s}, {r:?}");
                }
                let close = |a: f32, b: f32| (a - b).abs() <= 1e-6 * a.abs().max(1.0);
                let pairs = kept.pixels().iter().flatten().zip(grown.pixels().iter().flatten());
                assert!(pairs.into_iter().all(|(&a, &b)| close(a, b)), "factor {s}, {r:?}");
            }
        }
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
        assert_eq!(shrunk_temporal_prior(&ctx, 1).map(|p| p.to_full()), ctx.temporal_prior().map(|p| p.prior));
        let fine = ctx.temporal_prior().unwrap().prior;
        let shrunk = shrunk_temporal_prior(&ctx, 2).unwrap().to_full();
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
    fn depth_blocks_average_their_valid_depths_at_every_factor_and_window() {
        // Odd sizes, so that the last column and row of blocks are partial; depths valid, 0,
        // NaN, negative and +inf (sky) mixed.
        let (w, h) = (23, 14);
        let value = |u: usize, v: usize| match (u * 7 + v * 3) % 9 {
            0 => 0.0,
            1 => f32::NAN,
            2 => f32::INFINITY,
            3 => -1.0,
            k => 0.5 + k as f32 * (1.0 + u as f32 / 7.0),
        };
        let depth = DepthMap::from_fn(w, h, |u, v| [value(u, v)]);
        for s in [1, 2, 3, 4, 5] {
            let shrunk = shrink_depth(&depth, s);
            assert_eq!((shrunk.width(), shrunk.height()), (w.div_ceil(s), h.div_ceil(s)));
            for (cv, cu) in (0..shrunk.height()).flat_map(|cv| (0..shrunk.width()).map(move |cu| (cv, cu))) {
                let block: Vec<f32> = (cv * s..((cv + 1) * s).min(h))
                    .flat_map(|v| (cu * s..((cu + 1) * s).min(w)).map(move |u| value(u, v)))
                    .collect();
                let valid: Vec<f64> = block.iter().filter(|z| is_valid_depth(**z)).map(|&z| z as f64).collect();
                let expected = if !valid.is_empty() {
                    (valid.iter().sum::<f64>() / valid.len() as f64) as f32
                } else if block.contains(&f32::INFINITY) {
                    f32::INFINITY
                } else {
                    0.0
                };
                assert_eq!(shrunk.get(cu, cv), [expected], "factor {s}, block ({cu}, {cv})");
            }
            // A window is the same blocks as the whole.
            let window = Rect { x: 1, y: 1, width: shrunk.width() - 1, height: shrunk.height() - 1 };
            assert_eq!(
                shrink_depth_in(&depth, s, window),
                shrunk.crop(window.x, window.y, window.width, window.height),
                "factor {s}"
            );
        }
    }
}
