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

use crate::geometry::{DepthMap, VectorField};
use crate::infill::{InfillError, VectorPredictor};
use crate::nn::model::{IvpNet, NetInput};

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
    /// Cells of 64 pixels with 32 pixels of context: see PERFORMANCE.md, "Sparse inference".
    pub const DEFAULT: TileShape = TileShape { core: 64, margin: 32 };

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
}

/// What the network reads (`input`) and the cell inside it whose vectors are kept (`core`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tile {
    pub input: Rect,
    pub core: Rect,
}

/// The tiles of a `width` x `height` frame whose core holds at least one `marked` pixel, cores in
/// row-major order.
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
    let span = |start: usize, len: usize, limit: usize| {
        let (lo, hi) = (start.saturating_sub(shape.margin), (start + len + shape.margin).min(limit));
        (lo, hi - lo)
    };
    (0..rows * columns)
        .filter(|&i| active[i])
        .map(|i| {
            let (cx, cy) = ((i % columns) * shape.core, (i / columns) * shape.core);
            let core = Rect { x: cx, y: cy, width: shape.core.min(width - cx), height: shape.core.min(height - cy) };
            let ((x, w), (y, h)) = (span(cx, core.width, width), span(cy, core.height, height));
            Tile { input: Rect { x, y, width: w, height: h }, core }
        })
        .collect()
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
            by_size.entry((tile.input.width, tile.input.height)).or_default().push(*tile);
        }
        for ((tw, th), group) in by_size {
            for batch in group.chunks(MAX_TILES_PER_BATCH) {
                let crop = |channels: usize, value: &dyn Fn(usize, usize) -> f32| {
                    let mut data = vec![0f32; batch.len() * channels * tw * th];
                    for (tile, planes) in batch.iter().zip(data.chunks_exact_mut(channels * tw * th)) {
                        for (c, plane) in planes.chunks_exact_mut(tw * th).enumerate() {
                            for (row, out) in plane.chunks_exact_mut(tw).enumerate() {
                                let start = (tile.input.y + row) * w + tile.input.x;
                                for (col, o) in out.iter_mut().enumerate() {
                                    *o = value(start + col, c);
                                }
                            }
                        }
                    }
                    Tensor::from_vec(data, (batch.len(), channels, th, tw), &Device::Cpu)
                };
                let (p, d) = (prior.pixels(), depth.pixels());
                let prior_t = crop(2, &|i, c| p[i][c])?;
                let depth_t = crop(1, &|i, _| d[i][0])?;
                let mask_t = crop(1, &|i, _| f32::from(u8::from(holes[i])))?;
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
                    for v in tile.core.y..tile.core.y + tile.core.height {
                        for u in tile.core.x..tile.core.x + tile.core.width {
                            let i = v * w + u;
                            if holes[i] {
                                let j = (v - tile.input.y) * tw + (u - tile.input.x);
                                field[i] = [a[j], b[j]];
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
        self.predict_tiles(prior, depth, holes, &tiles).map_err(|e| InfillError::Other(format!("network: {e}")))
    }
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
        assert_eq!(
            tiles,
            [
                Tile { core: rect(0, 0, 32, 32), input: rect(0, 0, 48, 48) },
                Tile { core: rect(32, 32, 32, 32), input: rect(16, 16, 64, 54) },
                Tile { core: rect(96, 64, 4, 6), input: rect(80, 48, 20, 22) },
            ]
        );
        assert!(tiles.iter().all(|t| t.input.x % TILE_ALIGN == 0 && t.input.y % TILE_ALIGN == 0));
        assert!(plan_tiles(w, h, &vec![false; w * h], shape).is_empty());
        assert!(TileShape::new(24, 16).is_err() && TileShape::new(32, 8).is_err() && TileShape::new(0, 0).is_err());
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
    fn tiles_with_a_margin_beyond_the_receptive_field_match_a_dense_pass() {
        let (net, _) = IvpNet::seeded(ModelConfig { variant: Variant::Full, width_mult: 0.125 }, 5).unwrap();
        let (w, h) = (480, 320);
        let (prior, depth, holes) = frame(w, h);
        let dense = net.predict(&prior, &depth, &holes).unwrap();
        // The U-Net and depth head together see about 70 pixels on each side.
        let tiled = TiledPredictor::new(&net, TileShape::new(32, 80).unwrap());
        let sparse = tiled.predict(&prior, &depth, &holes).unwrap();
        assert!(tiled.tiles_run() > 0 && tiled.dense_passes() == 0);
        let worst = dense.as_flat().iter().zip(sparse.as_flat()).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "largest difference {worst}");
        for (i, v) in sparse.pixels().iter().enumerate() {
            assert!(holes[i] || *v == [0.0, 0.0]);
        }
    }

    #[test]
    fn all_hole_frames_run_densely_and_results_do_not_depend_on_threads() {
        let (net, _) = IvpNet::seeded(ModelConfig { variant: Variant::Full, width_mult: 0.125 }, 6).unwrap();
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
        let (net, _) = IvpNet::seeded(ModelConfig { variant: Variant::Intensity, width_mult: 0.125 }, 1).unwrap();
        let (prior, depth, holes) = frame(176, 96);
        assert!(TiledPredictor::new(&net, TileShape::DEFAULT).predict(&prior, &depth, &holes).is_err());
    }
}
