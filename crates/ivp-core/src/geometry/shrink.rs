//! Frames shrunk by blocks of `s x s` pixels (ALGORITHMS.md §6.7): colours, depths, vectors and
//! masks, whole or in a window, each block made of its pixels by one rule ([`BlockRule`]). The
//! scaled temporal prior (`prior::scaled_target_prior`) and the frame the network sees at a
//! factor (`inference::NetworkFrame`) both shrink with these.

use rayon::prelude::*;

use crate::geometry::image::is_valid_depth;
use crate::geometry::{DepthMap, Image, Intrinsics, Rect, RgbImage, VectorField};

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
pub fn shrink_image_at(image: &RgbImage, s: usize, at: Option<&[bool]>) -> RgbImage {
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
pub fn shrink_depth_in(depth: &DepthMap, s: usize, window: Rect) -> DepthMap {
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
pub fn shrink_vectors_in(field: &VectorField, s: usize, window: Rect) -> VectorField {
    let rule = BlockRule { take: is_nonzero, flag: |_| false, finish: |sums, n, _| vector_block_mean(sums, n, s) };
    shrink_blocks(field, s, window, None, rule)
}

/// Whether a vector counts in its block's mean.
pub fn is_nonzero([x, y]: [f32; 2]) -> bool {
    x != 0.0 || y != 0.0
}

/// A block of `s x s` vectors whose `n` non-zero ones sum to `sums`, shrunk: their mean divided
/// by `s` (0 without any).
pub fn vector_block_mean(sums: [f64; 2], n: u32, s: usize) -> [f32; 2] {
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
pub fn blocks_with(w: usize, h: usize, s: usize, mask: &[bool], value: bool) -> Vec<bool> {
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
