//! Sparse inference: the network runs only on tiles of the frame whose core holds pixels to
//! predict, each read with a margin of context around it, and the tiles of one size go through
//! the network as one batch.
//!
//! Tiles sit on a grid of `core`-sized cells anchored at the frame's top-left corner, and `core`
//! and `margin` are multiples of 16, so every tile starts on a multiple of 16: the U-Net's four
//! stride-2 levels then sample the tile on the same grid as the whole frame, and a tile clipped
//! at the frame's border sees the same zero padding there as a dense pass. What differs from a
//! dense pass is only the context cut at the margin: a cell's vectors agree with the dense ones
//! as far as the margin covers what the network looks at (PERFORMANCE.md has the measurements
//! behind [`TileShape::DEFAULT`]).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};

use candle_core::{DType, Device, Tensor};

use crate::geometry::{DepthMap, Image, VectorField};
use crate::infill::{InfillError, VectorPredictor};
use crate::nn::model::{IvpNet, NetInput};
use crate::nn::tensor::to_batch_tensor;

/// Tiles start on multiples of this: the U-Net halves its maps four times.
pub const TILE_ALIGN: usize = 16;

/// Tiles of one size per network call: bounds the memory of a batch (about 40 MB of feature maps
/// per 128x128 tile at width 1).
const MAX_TILES_PER_BATCH: usize = 16;

/// The shape of the tiles of sparse inference, in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileShape {
    /// Side of the cells whose vectors a tile keeps.
    pub core: usize,
    /// Context read on every side of the core (clipped at the frame's border).
    pub margin: usize,
}

impl TileShape {
    /// Cells of 32 pixels with 32 pixels of context: the fastest shape whose vectors agree with a
    /// dense pass within 0.5 px of the frame the network sees at 99% of the disocclusion pixels
    /// on the Blender clips, at 320x240 and at 1080p shrunk by 2 (PERFORMANCE.md, "Choosing the
    /// tile shape").
    pub const DEFAULT: TileShape = TileShape { core: 32, margin: 32 };

    /// A shape whose core (at least 16) and margin are multiples of [`TILE_ALIGN`].
    pub fn new(core: usize, margin: usize) -> Result<Self, String> {
        if core == 0 || !core.is_multiple_of(TILE_ALIGN) || !margin.is_multiple_of(TILE_ALIGN) {
            return Err(format!(
                "tile core {core} and margin {margin} must be multiples of {TILE_ALIGN} (core at least {TILE_ALIGN})"
            ));
        }
        Ok(Self { core, margin })
    }
}

impl Default for TileShape {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// An axis-aligned rectangle of pixels: columns `x..x + width`, rows `y..y + height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Rect {
    pub fn area(&self) -> usize {
        self.width * self.height
    }

    /// The smallest rectangle that holds both.
    pub fn union(&self, other: &Rect) -> Rect {
        let (x, y) = (self.x.min(other.x), self.y.min(other.y));
        let right = (self.x + self.width).max(other.x + other.width);
        let bottom = (self.y + self.height).max(other.y + other.height);
        Rect { x, y, width: right - x, height: bottom - y }
    }
}

/// What the network reads (`input`), and the cells inside it whose vectors are kept (`cores`):
/// each core lies inside `input` with `margin` pixels of context on every side the frame allows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tile {
    pub input: Rect,
    pub cores: Vec<Rect>,
}

/// The tiles of a `width` x `height` frame that cover every cell holding a `marked` pixel.
///
/// Each such cell (`core` pixels on a side) needs itself plus `margin` pixels around it. Cells
/// whose needs overlap or touch form a group. A group is cut in two at the median of its cells
/// along the longer side of its needs' bounding box, each half is planned the same way, and the
/// halves' tiles are kept when they read fewer pixels together than the box; otherwise the box is
/// one tile. Holes are thin slivers along object edges: a sliver stays one thin box, which saves
/// the margins that neighbouring cells would read twice, while the slivers of a frame with holes
/// everywhere join into one group whose box would be the whole frame, and the cuts keep the empty
/// space between them out. Tiles are in row-major order of their first cell; cores in row-major
/// order.
pub fn plan_tiles(width: usize, height: usize, marked: &[bool], shape: TileShape) -> Vec<Tile> {
    assert_eq!(marked.len(), width * height, "mask does not match {width}x{height}");
    let (columns, rows) = (width.div_ceil(shape.core), height.div_ceil(shape.core));
    let mut active = vec![false; columns * rows];
    for (v, row) in marked.chunks_exact(width.max(1)).enumerate() {
        let cells = &mut active[(v / shape.core) * columns..][..columns];
        for (u, _) in row.iter().enumerate().filter(|(_, &m)| m) {
            cells[u / shape.core] = true;
        }
    }
    let cells: Vec<usize> = (0..rows * columns).filter(|&i| active[i]).collect();
    let core_of = |cell: usize| {
        let (x, y) = ((cell % columns) * shape.core, (cell / columns) * shape.core);
        Rect { x, y, width: shape.core.min(width - x), height: shape.core.min(height - y) }
    };
    let need_of = |core: Rect| {
        let span = |start: usize, len: usize, limit: usize| {
            let (lo, hi) = (start.saturating_sub(shape.margin), (start + len + shape.margin).min(limit));
            (lo, hi - lo)
        };
        let ((x, w), (y, h)) = (span(core.x, core.width, width), span(core.y, core.height, height));
        Rect { x, y, width: w, height: h }
    };

    // Group cells whose needs overlap or touch: within `reach` cells of each other.
    let reach = 1 + 2 * shape.margin / shape.core;
    let mut group = UnionFind::new(cells.len());
    let index_of: std::collections::HashMap<usize, usize> = cells.iter().enumerate().map(|(i, &c)| (c, i)).collect();
    for (i, &cell) in cells.iter().enumerate() {
        let (cx, cy) = (cell % columns, cell / columns);
        for ny in cy..=(cy + reach).min(rows - 1) {
            for nx in cx.saturating_sub(reach)..=(cx + reach).min(columns - 1) {
                if let Some(&j) = index_of.get(&(ny * columns + nx)) {
                    if j > i {
                        group.join(i, j);
                    }
                }
            }
        }
    }
    let mut members: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for i in 0..cells.len() {
        members.entry(group.root(i)).or_default().push(i);
    }
    let mut groups: Vec<Vec<usize>> = members.into_values().collect();
    groups.sort_by_key(|g| g[0]);

    let mut tiles = Vec::new();
    for g in groups {
        let mut cores: Vec<Rect> = g.iter().map(|&i| core_of(cells[i])).collect();
        partition(&mut cores, &need_of, &mut tiles);
    }
    let row_major = |r: &Rect| (r.y, r.x);
    tiles.sort_by_key(|t| row_major(&t.cores[0]));
    tiles
}

/// Tiles for `cores` (one group): the cores are cut in two at the median of their positions
/// along the longer side of their needs' bounding box, each side is planned the same way, and
/// the two sides' tiles are kept when they read fewer pixels together than the bounding box,
/// else the box is one tile. Cores are in row-major order within a tile. Returns the pixels read.
///
/// A single cut cannot show that a ring of slivers is cheaper as four thin boxes (either side of
/// any cut still spans the ring), so the sides are planned before they are compared.
fn partition(cores: &mut [Rect], need_of: &impl Fn(Rect) -> Rect, tiles: &mut Vec<Tile>) -> usize {
    let whole = cores.iter().map(|&c| need_of(c)).reduce(|a, b| a.union(&b)).expect("a group has cores");
    let one_tile = |cores: &[Rect], tiles: &mut Vec<Tile>| {
        let mut cores = cores.to_vec();
        cores.sort_by_key(|r| (r.y, r.x));
        tiles.push(Tile { input: whole, cores });
        whole.area()
    };
    // Cut between two distinct positions along the longer side (else the other), nearest the
    // middle (the later one on a tie).
    let mut cut = None;
    for along_columns in [whole.width >= whole.height, whole.width < whole.height] {
        let position = |r: &Rect| if along_columns { (r.x, r.y) } else { (r.y, r.x) };
        cores.sort_by_key(position);
        let middle = cores.len() / 2;
        cut = (1..cores.len())
            .filter(|&k| position(&cores[k - 1]).0 != position(&cores[k]).0)
            .min_by_key(|&k| (k.abs_diff(middle), std::cmp::Reverse(k)));
        if cut.is_some() {
            break;
        }
    }
    let Some(k) = cut else { return one_tile(cores, tiles) };
    let first = tiles.len();
    let (left, right) = cores.split_at_mut(k);
    let pixels = partition(left, need_of, tiles) + partition(right, need_of, tiles);
    if pixels < whole.area() {
        return pixels;
    }
    tiles.truncate(first);
    one_tile(cores, tiles)
}

/// Disjoint sets of `0..n`, for grouping cells.
struct UnionFind(Vec<usize>);

impl UnionFind {
    fn new(n: usize) -> Self {
        Self((0..n).collect())
    }

    fn root(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }

    /// Joins the sets of `a` and `b`; the smaller root represents both (a fixed choice).
    fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.root(a), self.root(b));
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        self.0[hi] = lo;
    }
}

/// A network that predicts vectors tile by tile ([`plan_tiles`]), or in one dense pass when the
/// tiles would cover more pixels than the frame has.
#[derive(Debug)]
pub struct TiledPredictor<'a> {
    net: &'a IvpNet,
    shape: TileShape,
    tiles_run: AtomicUsize,
    dense_passes: AtomicUsize,
}

impl<'a> TiledPredictor<'a> {
    pub fn new(net: &'a IvpNet, shape: TileShape) -> Self {
        Self { net, shape, tiles_run: AtomicUsize::new(0), dense_passes: AtomicUsize::new(0) }
    }

    /// Tiles run through the network so far, over every call.
    pub fn tiles_run(&self) -> usize {
        self.tiles_run.load(Ordering::Relaxed)
    }

    /// Calls that ran densely because the tiles would have cost more.
    pub fn dense_passes(&self) -> usize {
        self.dense_passes.load(Ordering::Relaxed)
    }

    fn predict_tiles(
        &self,
        prior: &VectorField,
        depth: &DepthMap,
        holes: &[bool],
        tiles: &[Tile],
    ) -> candle_core::Result<VectorField> {
        let (w, h) = (prior.width(), prior.height());
        let mut out = VectorField::zeros(w, h);
        // Tiles of one input size share a batch; a BTreeMap keeps the order fixed.
        let mut by_size: BTreeMap<(usize, usize), Vec<Tile>> = BTreeMap::new();
        for tile in tiles {
            by_size.entry((tile.input.width, tile.input.height)).or_default().push(tile.clone());
        }
        for ((tw, th), group) in by_size {
            for batch in group.chunks(MAX_TILES_PER_BATCH) {
                // Each tile's window of the frame's inputs, stacked into one tensor per input.
                let priors: Vec<VectorField> = batch.iter().map(|t| prior.crop(t.input.x, t.input.y, tw, th)).collect();
                let depths: Vec<DepthMap> = batch.iter().map(|t| depth.crop(t.input.x, t.input.y, tw, th)).collect();
                let masks: Vec<DepthMap> = batch
                    .iter()
                    .map(|t| {
                        Image::from_fn(tw, th, |u, v| [f32::from(u8::from(holes[(t.input.y + v) * w + t.input.x + u]))])
                    })
                    .collect();
                let stack = |images: &[DepthMap]| to_batch_tensor(&images.iter().collect::<Vec<_>>());
                let prior_t = to_batch_tensor(&priors.iter().collect::<Vec<_>>())?;
                let (depth_t, mask_t) = (stack(&depths)?, stack(&masks)?);
                // The vector variants do not read the warped frame before compositing.
                let unused = Tensor::zeros((batch.len(), 3, th, tw), DType::F32, &Device::Cpu)?;
                let input = NetInput {
                    prior: &prior_t,
                    warped_depth: &depth_t,
                    mask: &mask_t,
                    warped: &unused,
                    last: None,
                    last_warped: None,
                };
                let vectors: Vec<f32> = self.net.raw_output(&input)?.flatten_all()?.to_vec1()?;
                let plane = tw * th;
                let field = out.pixels_mut();
                for (tile, values) in batch.iter().zip(vectors.chunks_exact(2 * plane)) {
                    let (a, b) = values.split_at(plane);
                    for core in &tile.cores {
                        for v in core.y..core.y + core.height {
                            for u in core.x..core.x + core.width {
                                let i = v * w + u;
                                if holes[i] {
                                    let j = (v - tile.input.y) * tw + (u - tile.input.x);
                                    field[i] = [a[j], b[j]];
                                }
                            }
                        }
                    }
                }
                self.tiles_run.fetch_add(batch.len(), Ordering::Relaxed);
            }
        }
        Ok(out)
    }
}

impl VectorPredictor for TiledPredictor<'_> {
    fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
        if !self.net.config().variant.predicts_vectors() {
            return Err(InfillError::Other("the intensity variant predicts colours, not vectors".into()));
        }
        let (w, h) = (prior.width(), prior.height());
        let tiles = plan_tiles(w, h, holes, self.shape);
        let tiled_area: usize = tiles.iter().map(|t| t.input.area()).sum();
        if tiled_area >= w * h {
            self.dense_passes.fetch_add(1, Ordering::Relaxed);
            return self.net.predict(prior, depth, holes);
        }
        let vectors =
            self.predict_tiles(prior, depth, holes, &tiles).map_err(|e| InfillError::Other(format!("network: {e}")))?;
        ensure_finite_vectors(vectors, holes)
    }
}

/// Refuses vectors with a NaN or infinite component at a hole pixel: broken weights or inputs
/// must not pass for a prediction (the iterative infilling would silently fall back to `fill`).
pub(crate) fn ensure_finite_vectors(vectors: VectorField, holes: &[bool]) -> Result<VectorField, InfillError> {
    let bad = vectors.pixels().iter().zip(holes).filter(|(v, &hole)| hole && !v.iter().all(|x| x.is_finite())).count();
    if bad == 0 {
        return Ok(vectors);
    }
    let total = holes.iter().filter(|&&h| h).count();
    Err(InfillError::Other(format!(
        "network: {bad} of {total} hole pixels got non-finite vectors (NaN or infinite): the model's weights or \
         inputs are broken"
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::model::{ModelConfig, Variant};

    fn marks(width: usize, height: usize, pixels: &[(usize, usize)]) -> Vec<bool> {
        let mut marked = vec![false; width * height];
        for &(u, v) in pixels {
            marked[v * width + u] = true;
        }
        marked
    }

    #[test]
    fn tiles_cover_marked_cells_and_clip_at_borders_and_corners() {
        let (w, h) = (100, 70);
        let shape = TileShape::new(32, 16).unwrap();
        let tiles = plan_tiles(w, h, &marks(w, h, &[(0, 0), (99, 69), (40, 35), (41, 36)]), shape);
        let rect = |x, y, width, height| Rect { x, y, width, height };
        // One group (within two cells of each other), whose bounding box (100x70) reads more
        // than the three cells' needs apart.
        assert_eq!(
            tiles,
            [
                Tile { cores: vec![rect(0, 0, 32, 32)], input: rect(0, 0, 48, 48) },
                Tile { cores: vec![rect(32, 32, 32, 32)], input: rect(16, 16, 64, 54) },
                Tile { cores: vec![rect(96, 64, 4, 6)], input: rect(80, 48, 20, 22) },
            ]
        );
        assert!(tiles.iter().all(|t| t.input.x % TILE_ALIGN == 0 && t.input.y % TILE_ALIGN == 0));
        assert!(plan_tiles(w, h, &vec![false; w * h], shape).is_empty());
        // A vertical sliver: nine cells in a column, read as one thin tile.
        let (w, h) = (200, 200);
        let sliver: Vec<(usize, usize)> = (20..150).flat_map(|v| (50..56).map(move |u| (u, v))).collect();
        let tiles = plan_tiles(w, h, &marks(w, h, &sliver), TileShape::new(16, 16).unwrap());
        assert_eq!(tiles.len(), 1);
        assert_eq!(tiles[0].input, rect(32, 0, 48, 176));
        assert_eq!(tiles[0].cores, (1..=9).map(|r| rect(48, 16 * r, 16, 16)).collect::<Vec<_>>());
        assert!(TileShape::new(24, 16).is_err() && TileShape::new(32, 8).is_err() && TileShape::new(0, 0).is_err());
    }

    #[test]
    fn a_ring_of_holes_is_cut_into_its_sides() {
        // The outline of a square: one group of cells whose bounding box is nearly the frame.
        let (w, h) = (640, 640);
        let ring: Vec<(usize, usize)> = (0..w * h)
            .map(|i| (i % w, i / w))
            .filter(|&(u, v)| (40..600).contains(&u) && (40..600).contains(&v))
            .filter(|&(u, v)| !((44..596).contains(&u) && (44..596).contains(&v)))
            .collect();
        let marked = marks(w, h, &ring);
        let shape = TileShape::new(16, 32).unwrap();
        let tiles = plan_tiles(w, h, &marked, shape);
        let pixels: usize = tiles.iter().map(|t| t.input.area()).sum();
        // The bounding box is the whole frame; four thin sides would read 44% of it.
        assert!(tiles.len() >= 4 && pixels * 5 < w * h * 3, "{} tiles read {pixels} pixels", tiles.len());
        // Every marked pixel lies in exactly one core, and each core has its margin in its tile
        // wherever the frame allows.
        for &(u, v) in &ring {
            let holders: Vec<(&Tile, &Rect)> = tiles
                .iter()
                .flat_map(|t| t.cores.iter().map(move |c| (t, c)))
                .filter(|(_, c)| (c.x..c.x + c.width).contains(&u) && (c.y..c.y + c.height).contains(&v))
                .collect();
            assert_eq!(holders.len(), 1, "({u}, {v})");
            let (tile, core) = holders[0];
            let (i, c) = (tile.input, core);
            assert!(i.x <= c.x.saturating_sub(32) && i.y <= c.y.saturating_sub(32));
            assert!(i.x + i.width >= (c.x + c.width + 32).min(w) && i.y + i.height >= (c.y + c.height + 32).min(h));
        }
    }

    /// A frame with two hole patches, one touching the right border.
    fn frame(w: usize, h: usize) -> (VectorField, DepthMap, Vec<bool>) {
        let holes: Vec<bool> =
            (0..w * h).map(|i| matches!((i % w, i / w), (20..=27, 30..=60) | (150..=159, 5..=12))).collect();
        let prior = VectorField::from_fn(w, h, |u, v| [((u * 7 + v) % 13) as f32 * 0.3 - 2.0, (v % 5) as f32 * 0.4]);
        let depth = DepthMap::from_fn(w, h, |u, v| [if holes[v * w + u] { 0.0 } else { 1.0 + (u as f32 * 0.05) }]);
        (prior, depth, holes)
    }

    #[test]
    fn non_finite_vectors_at_holes_are_an_error() {
        let holes = [false, true, true, false];
        let ok = VectorField::from_pixels(2, 2, vec![[f32::NAN, 0.0], [1.0, 2.0], [0.5, -3.0], [f32::INFINITY, 0.0]]);
        assert!(ensure_finite_vectors(ok, &holes).is_ok(), "values outside holes are ignored");
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let v = VectorField::from_pixels(2, 2, vec![[0.0; 2], [1.0, bad], [0.5, -3.0], [0.0; 2]]);
            let err = ensure_finite_vectors(v, &holes).unwrap_err().to_string();
            assert!(
                err.contains("network:") && err.contains("1 of 2 hole pixels") && err.contains("non-finite"),
                "{err}"
            );
        }
    }

    /// A network whose weights are all NaN: every prediction must be refused, dense or tiled.
    #[test]
    fn a_network_with_nan_weights_is_refused_dense_and_tiled() {
        let (net, varmap) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        for var in varmap.all_vars() {
            let nan = Tensor::full(f32::NAN, var.shape(), &Device::Cpu).unwrap();
            var.set(&nan).unwrap();
        }
        let (w, h) = (480, 320);
        let (prior, depth, holes) = frame(w, h);
        let err = net.predict(&prior, &depth, &holes).unwrap_err().to_string();
        assert!(err.contains("non-finite vectors"), "{err}");
        let tiled = TiledPredictor::new(&net, TileShape::new(32, 80).unwrap());
        let err = tiled.predict(&prior, &depth, &holes).unwrap_err().to_string();
        assert!(tiled.tiles_run() > 0, "the sparse path must be the one tested");
        assert!(err.contains("non-finite vectors"), "{err}");
    }

    #[test]
    fn tiles_with_a_margin_beyond_the_receptive_field_match_a_dense_pass() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        let (w, h) = (480, 320);
        let (prior, depth, holes) = frame(w, h);
        let dense = net.predict(&prior, &depth, &holes).unwrap();
        // The U-Net and depth head together see about 70 pixels on each side.
        let tiled = TiledPredictor::new(&net, TileShape::new(32, 80).unwrap());
        let sparse = tiled.predict(&prior, &depth, &holes).unwrap();
        assert!(tiled.tiles_run() > 0 && tiled.dense_passes() == 0);
        let worst = dense.as_flat().iter().zip(sparse.as_flat()).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "largest difference {worst}");
        // Without context the tiles do differ: the comparison above can fail.
        let blind = TiledPredictor::new(&net, TileShape::new(32, 0).unwrap()).predict(&prior, &depth, &holes).unwrap();
        let worst = dense.as_flat().iter().zip(blind.as_flat()).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst > 1e-2, "a margin of 0 should change the vectors, largest difference {worst}");
        for (i, v) in sparse.pixels().iter().enumerate() {
            assert!(holes[i] || *v == [0.0, 0.0]);
        }
    }

    #[test]
    fn all_hole_frames_run_densely_and_results_do_not_depend_on_threads() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 6).unwrap();
        let (w, h) = (96, 80);
        let (prior, depth, _) = frame(w, h);
        let all = vec![true; w * h];
        let tiled = TiledPredictor::new(&net, TileShape::DEFAULT);
        let out = tiled.predict(&prior, &depth, &all).unwrap();
        assert_eq!((tiled.dense_passes(), tiled.tiles_run()), (1, 0));
        assert_eq!(out, net.predict(&prior, &depth, &all).unwrap());

        let (w, h) = (176, 96);
        let (prior, depth, holes) = frame(w, h);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| TiledPredictor::new(&net, TileShape::new(32, 16).unwrap()).predict(&prior, &depth, &holes))
                .unwrap()
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn the_intensity_variant_is_refused() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Intensity, 0.125), 1).unwrap();
        let (prior, depth, holes) = frame(176, 96);
        assert!(TiledPredictor::new(&net, TileShape::DEFAULT).predict(&prior, &depth, &holes).is_err());
    }
}
