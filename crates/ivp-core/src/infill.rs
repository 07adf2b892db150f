//! Infillers: every method that turns a warped frame with holes into a full frame, behind one trait.
//!
//! Every method infills the disocclusions its own way; the new regions get one common rule
//! ([`fill_new_regions`]) so that whole-frame metrics compare like with like (SPEC §4.1).
//!
//! Classical methods: `copy` (the last rendered frame), `warp` (the warped frame, disocclusions
//! black), `fill` (each disocclusion copies its background neighbour), `oracle` (fictitious
//! vectors measured on the ground truth, an upper bound for vector prediction) and `telea`
//! (OpenCV's Telea inpainting of the disocclusions, radius 5, in `inpaint.rs`).

use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::image::is_valid_depth;
use crate::inpaint::Telea;
use crate::prior::estimate_fictitious_vectors_on;
use crate::{DepthMap, HoleMask, Intrinsics, PixelClass, RgbImage, VectorField, Warp, WorldToCamera};

/// A rendered frame as an infiller sees it.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    pub image: &'a RgbImage,
    pub depth: &'a DepthMap,
    pub pose: &'a WorldToCamera,
}

/// Everything a method may use to predict frame `t = n + 1`.
#[derive(Clone, Copy, Debug)]
pub struct InfillContext<'a> {
    pub intrinsics: &'a Intrinsics,
    /// Frame `n`, the last rendered frame.
    pub last: FrameView<'a>,
    /// Frame `n - 2`, for the temporal prior; `None` at the start of a sequence.
    pub before_last: Option<FrameView<'a>>,
    /// The pose of the frame to predict (known from the head tracker).
    pub target_pose: &'a WorldToCamera,
    /// Frame `n` warped into the target view (computed once, shared by all methods).
    pub warped: &'a Warp,
    /// The target frame itself; only methods that say they use ground truth may read it.
    pub ground_truth: Option<&'a RgbImage>,
}

/// The prediction of one frame and where the method spent its time.
#[derive(Clone, Debug)]
pub struct Infilled {
    pub image: RgbImage,
    /// Time by stage (`"prior"`, `"network"`, `"infill"`), in the order the stages ran.
    pub stages: Vec<(&'static str, Duration)>,
}

#[derive(Debug, thiserror::Error)]
pub enum InfillError {
    #[error("method `{0}` needs the ground-truth target frame, which this context does not have")]
    NeedsGroundTruth(&'static str),
    #[error("{0}")]
    Other(String),
}

/// A method that predicts a frame from its warped version.
pub trait Infiller: Send + Sync {
    /// The name used on the command line and in tables.
    fn name(&self) -> &str;

    /// True for methods that read the target frame: every output must say so.
    fn uses_ground_truth(&self) -> bool {
        false
    }

    /// False for methods that ignore [`InfillContext::warped`]: their time excludes the warp.
    fn uses_warp(&self) -> bool {
        true
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError>;
}

// ---------------------------------------------------------------------------------------------
// Nearest known pixels along rows and columns
// ---------------------------------------------------------------------------------------------

/// A pixel `(u, v)`: column, row.
pub type Pixel = (usize, usize);

/// The four search directions, in the order that breaks every tie in this crate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    Left,
    Right,
    Up,
    Down,
}

impl Direction {
    /// Left, right, up, down: the tie-break order.
    pub const ALL: [Direction; 4] = [Direction::Left, Direction::Right, Direction::Up, Direction::Down];

    /// The neighbour one pixel away in this direction, if it is inside a `width` x `height` frame.
    #[inline]
    pub fn step(self, (u, v): Pixel, width: usize, height: usize) -> Option<Pixel> {
        match self {
            Direction::Left => u.checked_sub(1).map(|u| (u, v)),
            Direction::Right => (u + 1 < width).then_some((u + 1, v)),
            Direction::Up => v.checked_sub(1).map(|v| (u, v)),
            Direction::Down => (v + 1 < height).then_some((u, v + 1)),
        }
    }
}

/// For every pixel, the nearest known pixel strictly beyond it in each of the four directions.
///
/// Built in O(pixels) once per mask, so that searches from large holes (a frame that is all hole)
/// cost the same as from small ones, and walking from one known pixel to the next known pixel
/// along a direction (skipping holes) is a single lookup.
#[derive(Clone, Debug)]
pub struct NearestKnown {
    width: usize,
    height: usize,
    /// Column of the nearest known pixel to the left, or [`Self::NONE`].
    left: Vec<u32>,
    /// Column of the nearest known pixel to the right, or [`Self::NONE`].
    right: Vec<u32>,
    /// Row of the nearest known pixel above, or [`Self::NONE`].
    up: Vec<u32>,
    /// Row of the nearest known pixel below, or [`Self::NONE`].
    down: Vec<u32>,
}

impl NearestKnown {
    const NONE: u32 = u32::MAX;

    /// Panics if `known.len() != width * height` or a side does not fit in `u32`.
    pub fn new(width: usize, height: usize, known: &[bool]) -> Self {
        assert_eq!(known.len(), width * height, "known mask does not match {width}x{height}");
        assert!(width < Self::NONE as usize && height < Self::NONE as usize, "frame too large");
        let (left, right) = Self::along_rows(width, known);
        let (up, down) = Self::along_columns(width, height, known);
        Self { width, height, left, right, up, down }
    }

    fn along_rows(width: usize, known: &[bool]) -> (Vec<u32>, Vec<u32>) {
        let mut left = vec![Self::NONE; known.len()];
        let mut right = vec![Self::NONE; known.len()];
        let chunk = width.max(1);
        left.par_chunks_mut(chunk).zip(right.par_chunks_mut(chunk)).zip(known.par_chunks(chunk)).for_each(
            |((left, right), known)| {
                let mut last = Self::NONE;
                for u in 0..known.len() {
                    left[u] = last;
                    if known[u] {
                        last = u as u32;
                    }
                }
                last = Self::NONE;
                for u in (0..known.len()).rev() {
                    right[u] = last;
                    if known[u] {
                        last = u as u32;
                    }
                }
            },
        );
        (left, right)
    }

    fn along_columns(width: usize, height: usize, known: &[bool]) -> (Vec<u32>, Vec<u32>) {
        let mut up = vec![Self::NONE; known.len()];
        let mut down = vec![Self::NONE; known.len()];
        // Each row follows from the one before it (above for `up`, below for `down`).
        for v in 1..height {
            let (done, row) = up.split_at_mut(v * width);
            let previous = &done[(v - 1) * width..];
            let previous_known = &known[(v - 1) * width..v * width];
            for u in 0..width {
                row[u] = if previous_known[u] { (v - 1) as u32 } else { previous[u] };
            }
        }
        for v in (0..height.saturating_sub(1)).rev() {
            let (row, done) = down.split_at_mut((v + 1) * width);
            let row = &mut row[v * width..];
            let next_known = &known[(v + 1) * width..(v + 2) * width];
            for u in 0..width {
                row[u] = if next_known[u] { (v + 1) as u32 } else { done[u] };
            }
        }
        (up, down)
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The nearest known pixel strictly beyond `p` in direction `dir`.
    #[inline]
    pub fn beyond(&self, p: Pixel, dir: Direction) -> Option<Pixel> {
        let (u, v) = p;
        let i = v * self.width + u;
        match dir {
            Direction::Left | Direction::Right => {
                let col = if dir == Direction::Left { self.left[i] } else { self.right[i] };
                (col != Self::NONE).then_some((col as usize, v))
            }
            Direction::Up | Direction::Down => {
                let row = if dir == Direction::Up { self.up[i] } else { self.down[i] };
                (row != Self::NONE).then_some((u, row as usize))
            }
        }
    }

    /// The nearest known pixels of `p` in the order of [`Direction::ALL`].
    #[inline]
    pub fn around(&self, p: Pixel) -> [Option<Pixel>; 4] {
        Direction::ALL.map(|dir| self.beyond(p, dir))
    }
}

/// City-block distance (the pixels compared here always share a row or a column).
#[inline]
fn distance(a: Pixel, b: Pixel) -> usize {
    a.0.abs_diff(b.0) + a.1.abs_diff(b.1)
}

/// Of two pixels on either side of `p`, the closer one; the first on a tie or when only it exists.
fn closer(p: Pixel, first: Option<Pixel>, second: Option<Pixel>) -> Option<Pixel> {
    match (first, second) {
        (Some(a), Some(b)) => Some(if distance(b, p) < distance(a, p) { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// The pixel a new-region pixel copies: the nearest known pixel along its row (tie: left), else
/// along its column (tie: up).
pub fn new_region_source(nearest: &NearestKnown, p: Pixel) -> Option<Pixel> {
    let along_row = closer(p, nearest.beyond(p, Direction::Left), nearest.beyond(p, Direction::Right));
    along_row.or_else(|| closer(p, nearest.beyond(p, Direction::Up), nearest.beyond(p, Direction::Down)))
}

/// The pixel the `fill` rule copies into hole pixel `p`: of the nearest known pixels in the four
/// directions, the one with the largest warped depth (the background); ties go to the first of
/// left, right, up, down. A known pixel without a valid depth loses to any with one.
pub fn background_source(nearest: &NearestKnown, warped_depth: &DepthMap, p: Pixel) -> Option<Pixel> {
    let depth_key = |(u, v): Pixel| {
        let z = warped_depth.at(u, v);
        if is_valid_depth(z) {
            z
        } else {
            f32::NEG_INFINITY
        }
    };
    let mut best: Option<(Pixel, f32)> = None;
    for q in nearest.around(p).into_iter().flatten() {
        let z = depth_key(q);
        if best.is_none_or(|(_, best_z)| z > best_z) {
            best = Some((q, z));
        }
    }
    best.map(|(q, _)| q)
}

/// Copies into every pixel of class `class` the pixel `source` names for it (if any).
///
/// Sources must be known pixels: they are never written here, so the copies can be planned in
/// parallel and applied in any order with the same result.
fn copy_from_sources(
    image: &mut RgbImage,
    holes: &HoleMask,
    class: PixelClass,
    source: impl Fn(Pixel) -> Option<Pixel> + Sync,
) {
    let w = image.width();
    let copies: Vec<(usize, usize)> = (0..image.height())
        .into_par_iter()
        .flat_map_iter(|v| {
            let source = &source;
            (0..w).filter(move |&u| holes.class(u, v) == class).filter_map(move |u| {
                let (su, sv) = source((u, v))?;
                debug_assert!(holes.is_known(su, sv), "source ({su}, {sv}) is a hole");
                Some((v * w + u, sv * w + su))
            })
        })
        .collect();
    let pixels = image.pixels_mut();
    for (dst, src) in copies {
        pixels[dst] = pixels[src];
    }
}

fn assert_mask_matches(image: &RgbImage, holes: &HoleMask) {
    assert!(
        image.width() == holes.width() && image.height() == holes.height(),
        "image {}x{} and hole mask {}x{} differ in size",
        image.width(),
        image.height(),
        holes.width(),
        holes.height()
    );
}

// ---------------------------------------------------------------------------------------------
// Filling rules
// ---------------------------------------------------------------------------------------------

/// The common new-region rule of SPEC §4.1: every new-region pixel copies the nearest known pixel
/// along its row (tie: left), else along its column (tie: up), else stays as it is. Reads known
/// pixels only, so it can run before or after the disocclusions are infilled.
pub fn fill_new_regions(image: &mut RgbImage, holes: &HoleMask) {
    assert_mask_matches(image, holes);
    let nearest = NearestKnown::new(holes.width(), holes.height(), &holes.known());
    copy_from_sources(image, holes, PixelClass::NewRegion, |p| new_region_source(&nearest, p));
}

/// The `fill` rule: every disocclusion pixel copies, of the nearest known pixels in the four
/// directions, the one with the largest warped depth (a disocclusion is background uncovered
/// behind a foreground object, so the farther side is the likelier match).
pub fn fill_disocclusions_background(image: &mut RgbImage, warped_depth: &DepthMap, holes: &HoleMask) {
    assert_mask_matches(image, holes);
    assert!(image.same_size(warped_depth), "image and warped depth differ in size");
    let nearest = NearestKnown::new(holes.width(), holes.height(), &holes.known());
    copy_from_sources(image, holes, PixelClass::Disocclusion, |p| background_source(&nearest, warped_depth, p));
}

/// Copies `source` at `p + vector` into every pixel `p` whose (integer) vector is not zero.
/// The targets must be known pixels of `source` inside the frame (fictitious vectors are).
fn copy_along_vectors(image: &mut RgbImage, source: &RgbImage, vectors: &VectorField) {
    let w = image.width();
    image.pixels_mut().par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
        for (u, out) in row.iter_mut().enumerate() {
            let [a, b] = vectors.get(u, v);
            if a != 0.0 || b != 0.0 {
                let su = (u as f32 + a).round() as usize;
                let sv = (v as f32 + b).round() as usize;
                *out = source.get(su, sv);
            }
        }
    });
}

/// SPEC §6.3 at test time: the bilinear read of `image` at `(x, y)` over the corners that are
/// known and inside the frame, with the bilinear weights renormalised over them.
///
/// A corner whose bilinear weight is zero (the read sits exactly on a row or column) is not a
/// corner of the read. `None` when no corner remains, or `(x, y)` is not finite.
pub fn sample_known_bilinear(image: &RgbImage, known: &[bool], x: f32, y: f32) -> Option<[f32; 3]> {
    crate::iterative::sample_known(image, known, x, y)
}

// ---------------------------------------------------------------------------------------------
// Classical infillers
// ---------------------------------------------------------------------------------------------

/// The names of the classical methods, as on the command line.
pub const CLASSICAL_METHODS: &[&str] = &["copy", "warp", "fill", "oracle", "telea"];

/// The classical method called `name`, or `None` for any other name.
pub fn classical_infiller(name: &str) -> Option<Box<dyn Infiller>> {
    match name {
        "copy" => Some(Box::new(CopyLast)),
        "warp" => Some(Box::new(WarpOnly)),
        "fill" => Some(Box::new(BackgroundFill)),
        "oracle" => Some(Box::new(Oracle)),
        "telea" => Some(Box::new(Telea::default())),
        _ => None,
    }
}

/// Runs `f` and measures how long it took.
fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let start = Instant::now();
    let out = f();
    (out, start.elapsed())
}

pub(crate) fn infilled_in_one_stage(image: RgbImage, elapsed: Duration) -> Infilled {
    Infilled { image, stages: vec![("infill", elapsed)] }
}

/// `copy`: the last rendered frame as it is (no warp, no new-region rule).
#[derive(Clone, Copy, Debug, Default)]
pub struct CopyLast;

impl Infiller for CopyLast {
    fn name(&self) -> &str {
        "copy"
    }

    fn uses_warp(&self) -> bool {
        false
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let (image, elapsed) = timed(|| ctx.last.image.clone());
        Ok(infilled_in_one_stage(image, elapsed))
    }
}

/// `warp`: the warped frame with black disocclusions and the common new-region rule.
#[derive(Clone, Copy, Debug, Default)]
pub struct WarpOnly;

impl Infiller for WarpOnly {
    fn name(&self) -> &str {
        "warp"
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let warped = ctx.warped;
        let (image, elapsed) = timed(|| {
            let mut image = warped.image.clone();
            // Holes of a warp are already black; say so here rather than rely on it.
            for (p, class) in image.pixels_mut().iter_mut().zip(warped.holes.classes()) {
                if *class == PixelClass::Disocclusion {
                    *p = [0.0; 3];
                }
            }
            fill_new_regions(&mut image, &warped.holes);
            image
        });
        Ok(infilled_in_one_stage(image, elapsed))
    }
}

/// `fill`: every disocclusion copies its background neighbour ([`fill_disocclusions_background`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct BackgroundFill;

impl Infiller for BackgroundFill {
    fn name(&self) -> &str {
        "fill"
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let warped = ctx.warped;
        let (image, elapsed) = timed(|| {
            let mut image = warped.image.clone();
            fill_disocclusions_background(&mut image, &warped.depth, &warped.holes);
            fill_new_regions(&mut image, &warped.holes);
            image
        });
        Ok(infilled_in_one_stage(image, elapsed))
    }
}

/// `oracle`: the fictitious vectors of SPEC §6.2 measured on the target frame itself, i.e. the
/// best a vector predictor restricted to the four directions could do. Disocclusions where no
/// direction matches (vector 0) take the `fill` value. Reads the ground truth.
#[derive(Clone, Copy, Debug, Default)]
pub struct Oracle;

impl Infiller for Oracle {
    fn name(&self) -> &str {
        "oracle"
    }

    fn uses_ground_truth(&self) -> bool {
        true
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let ground_truth = ctx.ground_truth.ok_or(InfillError::NeedsGroundTruth("oracle"))?;
        let warped = ctx.warped;
        if !ground_truth.same_size(&warped.image) {
            return Err(InfillError::Other(format!(
                "ground truth is {}x{} but the warped frame is {}x{}",
                ground_truth.width(),
                ground_truth.height(),
                warped.image.width(),
                warped.image.height()
            )));
        }
        let holes = &warped.holes;
        let (vectors, prior_elapsed) =
            timed(|| estimate_fictitious_vectors_on(&holes.known(), &holes.disocclusions(), ground_truth));
        let (image, infill_elapsed) = timed(|| {
            let mut image = warped.image.clone();
            // `fill` everywhere first, then the vectors overwrite where they exist: both read
            // known pixels only, so this equals "fill where the vector is 0".
            fill_disocclusions_background(&mut image, &warped.depth, holes);
            copy_along_vectors(&mut image, &warped.image, &vectors);
            fill_new_regions(&mut image, holes);
            image
        });
        Ok(Infilled { image, stages: vec![("prior", prior_elapsed), ("infill", infill_elapsed)] })
    }
}

/// A box in front of a wall seen by a camera that slides along x: every frame is rendered
/// analytically, so warps of it can be checked against the true frames.
#[cfg(test)]
pub(crate) mod test_scene {
    use glam::{DMat4, DVec3};

    use crate::{DepthMap, Image, Intrinsics, RgbImage, WorldToCamera};

    pub const WIDTH: usize = 64;
    pub const HEIGHT: usize = 48;
    pub const WALL_Z: f64 = 10.0;
    pub const BOX_Z: f64 = 2.0;
    pub const BOX_COLOUR: [f32; 3] = [1.0, 0.0, 0.0];
    /// World x range of the box: columns 20..30 when the camera is at x = 0.
    const BOX_X: (f64, f64) = (-0.235, -0.045);
    const BOX_ROWS: std::ops::RangeInclusive<usize> = 10..=37;

    pub fn intrinsics() -> Intrinsics {
        Intrinsics::new(100.0, 100.0, 31.5, 23.5)
    }

    /// Stripes along rows only, far from the box colour: a horizontal shift matches exactly.
    pub fn wall_colour(v: usize) -> [f32; 3] {
        let g = ((v * v * 7 + 3 * v) % 11) as f32 / 10.0;
        [0.0, g, 1.0]
    }

    /// Image, planar depth and pose of the camera at world `x = camera_x`.
    pub fn render(camera_x: f64) -> (RgbImage, DepthMap, WorldToCamera) {
        let k = intrinsics();
        let on_box = |u: usize, v: usize| {
            let x = (u as f64 - k.cx) / k.fx * BOX_Z + camera_x;
            BOX_ROWS.contains(&v) && (BOX_X.0..=BOX_X.1).contains(&x)
        };
        let image = Image::from_fn(WIDTH, HEIGHT, |u, v| if on_box(u, v) { BOX_COLOUR } else { wall_colour(v) });
        let depth = Image::from_fn(WIDTH, HEIGHT, |u, v| [if on_box(u, v) { BOX_Z } else { WALL_Z } as f32]);
        let pose = WorldToCamera(DMat4::from_translation(DVec3::new(-camera_x, 0.0, 0.0)));
        (image, depth, pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{relative_pose, warp_forward, Image};

    const RED: [f32; 3] = [1.0, 0.0, 0.0];
    const GREEN: [f32; 3] = [0.0, 1.0, 0.0];
    const BLUE: [f32; 3] = [0.0, 0.0, 1.0];

    fn classes_from_rows(rows: &[&str]) -> HoleMask {
        // K = known, N = new region, D = disocclusion.
        let classes = rows
            .iter()
            .flat_map(|r| r.chars())
            .map(|c| match c {
                'K' => PixelClass::Known,
                'N' => PixelClass::NewRegion,
                'D' => PixelClass::Disocclusion,
                _ => panic!("bad class {c}"),
            })
            .collect();
        HoleMask::from_classes(rows[0].len(), rows.len(), classes)
    }

    /// An image whose every pixel has a distinct colour, so a copy says where it came from.
    fn labelled(w: usize, h: usize) -> RgbImage {
        Image::from_fn(w, h, |u, v| [u as f32 / w as f32, v as f32 / h as f32, 0.5])
    }

    fn assert_all_finite(image: &RgbImage) {
        assert!(image.as_flat().iter().all(|x| x.is_finite()), "non-finite pixel");
    }

    #[test]
    fn nearest_known_finds_known_pixels_strictly_beyond() {
        let (w, h) = (7, 5);
        let known: Vec<bool> = (0..w * h).map(|i| i % 3 == 0).collect();
        let nearest = NearestKnown::new(w, h, &known);
        let is_known = |(u, v): Pixel| known[v * w + u];
        for v in 0..h {
            for u in 0..w {
                for dir in Direction::ALL {
                    // Walk one step at a time: the first known pixel met is the answer.
                    let mut walk = dir.step((u, v), w, h);
                    while let Some(q) = walk.filter(|&q| !is_known(q)) {
                        walk = dir.step(q, w, h);
                    }
                    assert_eq!(nearest.beyond((u, v), dir), walk, "({u}, {v}) {dir:?}");
                }
            }
        }
    }

    #[test]
    fn new_regions_copy_the_nearest_known_pixel_in_the_row_then_the_column() {
        let holes = classes_from_rows(&[
            "KNNKNNK", // (1,0): left at 1 beats right at 2; (2,0): right at 1; (4,0)/(5,0) likewise
            "KNKNNNN", // (1,1): tie between 0 and 2 -> left; (3..6,1): only the left one at 2
            "NNNNNNN", // nothing in the row: (0,2) column: up (0,1) at 1, down (0,4) at 2 -> up
            "NNNNNNN", // (0,3): up at 2, down at 1 -> down; (2,3): up (2,1) at 2, down (2,4) at 1 -> down
            "KNKNNNN", // column 4 has no known pixel: (4,2), (4,3) unchanged; (6,3): only up (6,0)
        ]);
        let original = labelled(7, 5);
        let mut image = original.clone();
        fill_new_regions(&mut image, &holes);
        let o = |u, v| original.get(u, v);
        let expected = [
            ((1, 0), o(0, 0)),
            ((2, 0), o(3, 0)),
            ((4, 0), o(3, 0)),
            ((5, 0), o(6, 0)),
            ((1, 1), o(0, 1)),
            ((5, 1), o(2, 1)),
            ((0, 2), o(0, 1)),
            ((2, 2), o(2, 1)),
            ((0, 3), o(0, 4)),
            ((2, 3), o(2, 4)),
            ((3, 2), o(3, 0)),
            ((4, 2), o(4, 2)),
            ((4, 3), o(4, 3)),
            ((6, 3), o(6, 0)),
        ];
        for ((u, v), want) in expected {
            assert_eq!(image.get(u, v), want, "({u}, {v})");
        }
        // Known pixels are never touched.
        for (i, class) in holes.classes().iter().enumerate() {
            if *class == PixelClass::Known {
                assert_eq!(image.pixels()[i], original.pixels()[i]);
            }
        }
    }

    #[test]
    fn new_region_rule_leaves_disocclusions_alone() {
        let holes = classes_from_rows(&["KKK", "KDK", "KKK"]);
        let mut image = Image::filled(3, 3, RED);
        image.set(1, 1, BLUE);
        fill_new_regions(&mut image, &holes);
        assert_eq!(image.get(1, 1), BLUE);
    }

    #[test]
    fn fill_copies_the_farthest_of_the_four_nearest_known_pixels() {
        let holes = classes_from_rows(&["KKKKK", "KKKKK", "KKDDK", "KKKKK", "KKKKK"]);
        // (2,2): left (1,2) near/red, right (4,2) far/blue, up and down middle/green.
        let mut depth = Image::filled(5, 5, [5.0]);
        depth.set(1, 2, [1.0]);
        depth.set(4, 2, [10.0]);
        let mut image = Image::filled(5, 5, GREEN);
        image.set(1, 2, RED);
        image.set(4, 2, BLUE);
        for (u, v) in [(2, 2), (3, 2)] {
            image.set(u, v, [0.0; 3]);
            depth.set(u, v, [0.0]);
        }
        let mut filled = image.clone();
        fill_disocclusions_background(&mut filled, &depth, &holes);
        assert_eq!(filled.get(2, 2), BLUE);
        assert_eq!(filled.get(3, 2), BLUE);

        // Ties: left and right equally far -> left; up and down only -> up.
        depth.set(1, 2, [10.0]);
        depth.set(2, 1, [10.0]);
        depth.set(2, 3, [10.0]);
        image.set(2, 1, [0.3; 3]);
        image.set(2, 3, [0.7; 3]);
        let mut filled = image.clone();
        fill_disocclusions_background(&mut filled, &depth, &holes);
        assert_eq!(filled.get(2, 2), RED);
        depth.set(1, 2, [1.0]);
        depth.set(4, 2, [1.0]);
        let mut filled = image.clone();
        fill_disocclusions_background(&mut filled, &depth, &holes);
        assert_eq!(filled.get(2, 2), [0.3; 3]);
    }

    #[test]
    fn fill_prefers_a_valid_depth_over_an_invalid_one() {
        let holes = classes_from_rows(&["KKK", "KDK", "KKK"]);
        let depth = Image::from_fn(3, 3, |u, _| [if u == 0 { f32::NAN } else { 0.5 }]);
        let mut image = labelled(3, 3);
        fill_disocclusions_background(&mut image, &depth, &holes);
        // Left has NaN depth, right (2,1) valid: right wins.
        assert_eq!(image.get(1, 1), labelled(3, 3).get(2, 1));
    }

    #[test]
    fn known_bilinear_read_renormalises_over_known_corners() {
        let image = Image::from_fn(4, 3, |u, v| [u as f32, v as f32, 1.0]);
        let all = vec![true; 12];
        let read = sample_known_bilinear(&image, &all, 1.25, 0.5).unwrap();
        assert!((read[0] - 1.25).abs() < 1e-6 && (read[1] - 0.5).abs() < 1e-6 && (read[2] - 1.0).abs() < 1e-6);
        // Corner (2, 1) unknown: the rest, weights 0.375, 0.125, 0.375 of (1,0), (2,0), (1,1), renormalised.
        let mut known = all.clone();
        known[4 + 2] = false;
        let read = sample_known_bilinear(&image, &known, 1.25, 0.5).unwrap();
        let total = 0.375 + 0.125 + 0.375;
        assert!((read[0] - (0.375 + 2.0 * 0.125 + 0.375) / total).abs() < 1e-6, "{read:?}");
        assert!((read[1] - 0.375 / total).abs() < 1e-6, "{read:?}");
        // Exactly on a pixel: only that pixel is a corner.
        assert_eq!(sample_known_bilinear(&image, &all, 2.0, 1.0), Some([2.0, 1.0, 1.0]));
        assert_eq!(sample_known_bilinear(&image, &known, 2.0, 1.0), None);
        // Half outside the frame: the in-frame corners only.
        assert_eq!(sample_known_bilinear(&image, &all, -0.5, 0.0), Some([0.0, 0.0, 1.0]));
        for (x, y) in [(-1.0, 0.0), (4.0, 1.0), (1.0, 3.0), (f32::NAN, 1.0), (1e30, 1.0), (f32::NEG_INFINITY, 0.0)] {
            assert_eq!(sample_known_bilinear(&image, &all, x, y), None, "({x}, {y})");
        }
        assert_eq!(sample_known_bilinear(&image, &[false; 12], 1.5, 1.5), None);
    }

    /// Frame n at camera x = 0.2 warped to the target at x = 0.3, with the target's truth.
    struct BoxScene {
        k: Intrinsics,
        last: (RgbImage, DepthMap, WorldToCamera),
        target: (RgbImage, DepthMap, WorldToCamera),
        warped: Warp,
    }

    impl BoxScene {
        fn new() -> Self {
            let k = test_scene::intrinsics();
            let last = test_scene::render(0.2);
            let target = test_scene::render(0.3);
            let warped = warp_forward(&last.0, &last.1, &k, &relative_pose(&last.2, &target.2));
            Self { k, last, target, warped }
        }

        fn context(&self, with_truth: bool) -> InfillContext<'_> {
            InfillContext {
                intrinsics: &self.k,
                last: FrameView { image: &self.last.0, depth: &self.last.1, pose: &self.last.2 },
                before_last: None,
                target_pose: &self.target.2,
                warped: &self.warped,
                ground_truth: with_truth.then_some(&self.target.0),
            }
        }

        fn disocclusions(&self) -> Vec<Pixel> {
            let (w, h) = (self.warped.image.width(), self.warped.image.height());
            (0..h)
                .flat_map(|v| (0..w).map(move |u| (u, v)))
                .filter(|&(u, v)| self.warped.holes.is_disocclusion(u, v))
                .collect()
        }
    }

    fn run(name: &str, ctx: &InfillContext<'_>) -> Infilled {
        classical_infiller(name).unwrap().infill(ctx).unwrap()
    }

    #[test]
    fn classical_methods_on_a_box_scene() {
        let scene = BoxScene::new();
        let holes = scene.disocclusions();
        assert!(holes.len() > 50, "the scene should open a disocclusion, got {}", holes.len());
        let ctx = scene.context(true);
        let truth = &scene.target.0;

        let copy = run("copy", &ctx);
        assert_eq!(copy.image, scene.last.0);

        let warp = run("warp", &ctx);
        assert!(holes.iter().all(|&(u, v)| warp.image.get(u, v) == [0.0; 3]));

        // The uncovered wall takes wall colour, never the box's.
        let fill = run("fill", &ctx);
        assert!(holes.iter().all(|&(u, v)| fill.image.get(u, v) != test_scene::BOX_COLOUR));

        // The wall's stripes run along rows: where the oracle finds a vector it reproduces the truth
        // exactly; elsewhere (next to the box, whose patches match nothing) it falls back to `fill`.
        let oracle = run("oracle", &ctx);
        let known = scene.warped.holes.known();
        let vectors = estimate_fictitious_vectors_on(&known, &scene.warped.holes.disocclusions(), truth);
        let mut with_vector = 0;
        for &(u, v) in &holes {
            if vectors.get(u, v) == [0.0, 0.0] {
                assert_eq!(oracle.image.get(u, v), fill.image.get(u, v), "({u}, {v})");
            } else {
                // Splatting divides by the accumulated weight: equal up to rounding.
                let (got, want) = (oracle.image.get(u, v), truth.get(u, v));
                assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-5), "({u}, {v}): {got:?} vs {want:?}");
                with_vector += 1;
            }
        }
        assert!(with_vector * 2 >= holes.len(), "vectors on only {with_vector} of {} pixels", holes.len());
        let stage_names: Vec<&str> = oracle.stages.iter().map(|(name, _)| *name).collect();
        assert_eq!(stage_names, ["prior", "infill"]);

        // Telea inpainting fills the disocclusions and leaves known pixels as they are.
        let telea = run("telea", &ctx);
        for (i, class) in scene.warped.holes.classes().iter().enumerate() {
            if *class == PixelClass::Known {
                assert_eq!(telea.image.pixels()[i], scene.warped.image.pixels()[i]);
            }
        }
        assert!(holes.iter().all(|&(u, v)| telea.image.get(u, v) != [0.0; 3]));

        // New regions (right border) are filled the same way by every method that warps.
        for out in [&warp, &fill, &oracle, &telea] {
            for (i, class) in scene.warped.holes.classes().iter().enumerate() {
                if *class == PixelClass::NewRegion {
                    assert_eq!(out.image.pixels()[i], fill.image.pixels()[i]);
                    assert_ne!(out.image.pixels()[i], [0.0; 3]);
                }
            }
            assert_all_finite(&out.image);
        }
    }

    #[test]
    fn oracle_follows_the_matching_texture_where_fill_follows_depth() {
        // Disocclusion at columns 5..=9, rows 2..=6. The truth continues the right side's row
        // stripes into the hole, but the left side is farther: `fill` copies the left texture,
        // the oracle's vectors find the right one.
        let (w, h) = (15, 9);
        let is_hole = |u: usize, v: usize| (5..=9).contains(&u) && (2..=6).contains(&v);
        let stripes = |v: usize| [0.05 * v as f32, 0.1, 0.0];
        let truth = Image::from_fn(w, h, |u, v| if u < 5 { [1.0, 1.0, 1.0] } else { stripes(v) });
        let known: Vec<bool> = (0..w * h).map(|i| !is_hole(i % w, i / w)).collect();
        let image = Image::from_fn(w, h, |u, v| if is_hole(u, v) { [0.0; 3] } else { truth.get(u, v) });
        let depth = Image::from_fn(w, h, |u, v| {
            [if is_hole(u, v) {
                0.0
            } else if u < 5 {
                10.0
            } else {
                1.0
            }]
        });
        let warped = warp_of(image, depth, &known);
        assert_eq!(warped.holes.count(PixelClass::Disocclusion), 25);
        let outputs = run_every_method(&warped, &truth);
        let (fill, oracle) = (&outputs[2].image, &outputs[3].image);
        for v in 2..=6 {
            // Column 7 on: the hole pixel's patch is all stripes, as is the right candidate's.
            for u in 7..=9 {
                assert_eq!(oracle.get(u, v), truth.get(u, v), "({u}, {v})");
                assert_eq!(fill.get(u, v), truth.get(4, v), "({u}, {v})");
            }
            // Columns 5, 6: the patch straddles both textures, no candidate is close: `fill`.
            for u in 5..=6 {
                assert_eq!(oracle.get(u, v), fill.get(u, v), "({u}, {v})");
            }
        }
    }

    #[test]
    fn oracle_needs_the_ground_truth_and_says_so() {
        let scene = BoxScene::new();
        let oracle = classical_infiller("oracle").unwrap();
        assert!(oracle.uses_ground_truth());
        assert!(matches!(oracle.infill(&scene.context(false)), Err(InfillError::NeedsGroundTruth("oracle"))));
        let small = Image::filled(3, 3, RED);
        let ctx = InfillContext { ground_truth: Some(&small), ..scene.context(false) };
        assert!(matches!(oracle.infill(&ctx), Err(InfillError::Other(_))));
    }

    #[test]
    fn registry_knows_exactly_the_classical_methods() {
        for &name in CLASSICAL_METHODS {
            let method = classical_infiller(name).unwrap();
            assert_eq!(method.name(), name);
            assert_eq!(method.uses_ground_truth(), name == "oracle");
        }
        assert!(classical_infiller("ivp").is_none());
        assert!(classical_infiller("").is_none());
    }

    /// A warp with the given image, depth and known mask, as the warper would return it.
    fn warp_of(image: RgbImage, depth: DepthMap, known: &[bool]) -> Warp {
        let holes = HoleMask::classify(image.width(), image.height(), known);
        Warp { image, depth, holes }
    }

    fn run_every_method(warped: &Warp, truth: &RgbImage) -> Vec<Infilled> {
        let k = Intrinsics::new(10.0, 10.0, 3.0, 2.0);
        let pose = WorldToCamera(glam::DMat4::IDENTITY);
        let ctx = InfillContext {
            intrinsics: &k,
            last: FrameView { image: truth, depth: &warped.depth, pose: &pose },
            before_last: None,
            target_pose: &pose,
            warped,
            ground_truth: Some(truth),
        };
        CLASSICAL_METHODS.iter().map(|name| run(name, &ctx)).collect()
    }

    #[test]
    fn all_hole_and_no_hole_frames_of_odd_size() {
        let (w, h) = (7, 5);
        let truth = labelled(w, h);
        // No holes: every warping method returns the warp untouched.
        let full = warp_of(truth.clone(), Image::filled(w, h, [3.0]), &vec![true; w * h]);
        for out in run_every_method(&full, &truth) {
            assert_eq!(out.image, truth);
        }
        // All holes: nothing to copy from; the warped frame (black) stays as it is.
        let empty = warp_of(Image::zeros(w, h), Image::zeros(w, h), &vec![false; w * h]);
        for out in &run_every_method(&empty, &truth)[1..] {
            assert!(out.image.as_flat().iter().all(|&x| x == 0.0));
        }
    }

    #[test]
    fn constant_scene_is_reproduced_by_every_method() {
        let (w, h) = (9, 7);
        let grey = [0.4, 0.4, 0.4];
        let truth = Image::filled(w, h, grey);
        // A disocclusion block in the middle and a new region on the right.
        let known: Vec<bool> =
            (0..w * h).map(|i| !((3..6).contains(&(i % w)) && (2..5).contains(&(i / w))) && i % w != w - 1).collect();
        let image = Image::from_fn(w, h, |u, v| if known[v * w + u] { grey } else { [0.0; 3] });
        let depth = Image::from_fn(w, h, |u, v| [if known[v * w + u] { 2.0 } else { 0.0 }]);
        let warped = warp_of(image, depth, &known);
        assert!(warped.holes.count(PixelClass::Disocclusion) == 9);
        let outputs = run_every_method(&warped, &truth);
        for (name, out) in CLASSICAL_METHODS.iter().zip(&outputs) {
            for v in 0..h {
                for u in 0..w {
                    let want = if *name == "warp" && warped.holes.is_disocclusion(u, v) { [0.0; 3] } else { grey };
                    assert_eq!(out.image.get(u, v), want, "{name} at ({u}, {v})");
                }
            }
        }
    }

    #[test]
    fn no_nan_from_nan_inputs() {
        let (w, h) = (11, 9);
        let truth = Image::from_fn(w, h, |u, v| if (u + v) % 4 == 0 { [f32::NAN; 3] } else { [0.5, 0.2, 0.9] });
        let known: Vec<bool> = (0..w * h).map(|i| !(4..7).contains(&(i % w)) || i / w == 0 || i / w == h - 1).collect();
        let image = Image::from_fn(w, h, |u, v| if known[v * w + u] { [0.1, 0.2, 0.3] } else { [0.0; 3] });
        let depth = Image::from_fn(w, h, |u, v| {
            [if !known[v * w + u] {
                0.0
            } else if u % 3 == 0 {
                f32::NAN
            } else {
                1.0 + u as f32
            }]
        });
        let warped = warp_of(image, depth, &known);
        assert!(warped.holes.count(PixelClass::Disocclusion) > 0);
        // `copy` returns the NaN-laden last frame as it is: skip it.
        for out in &run_every_method(&warped, &truth)[1..] {
            assert_all_finite(&out.image);
        }
    }
}
