//! The network as the [`VectorPredictor`] of the iterative infilling: [`NetworkPredictor`] runs
//! it densely or on tiles ([`Coverage`]), on the frame as it is or shrunk ([`NetworkFrame`]).
//!
//! One path serves every setting: a dense pass is a single tile whose input and core are the
//! whole frame, and the frame at factor 1 is read as it is.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};

use candle_core::{DType, Device, Tensor};
use rayon::prelude::*;

use crate::geometry::{DepthMap, Rect, VectorField};
use crate::inference::scaled::NetworkFrame;
use crate::inference::tiles::{plan_tiles, Tile, TileShape};
use crate::infill::{InfillError, VectorPredictor};
use crate::nn::model::{IvpNet, NetInput};
use crate::nn::ops::at_points::BatchPixel;
use crate::nn::ops::profile;
use crate::nn::tensor::to_batch_tensor;
use crate::prior::ScaledPrior;

/// Tiles of one size per network call: bounds the memory of a batch (about 40 MB of feature maps
/// per 128x128 tile at width 1).
const MAX_TILES_PER_BATCH: usize = 16;

/// How the network covers a frame at test time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coverage {
    /// One pass over the whole frame per iteration.
    Dense,
    /// Only the tiles that hold disocclusions still to fill ([`plan_tiles`]); dense when that is
    /// cheaper.
    Sparse(TileShape),
}

impl Default for Coverage {
    fn default() -> Self {
        Coverage::Sparse(TileShape::DEFAULT)
    }
}

/// A network that predicts vectors with a [`Coverage`] on the frame shrunk by `factor` (1: as it
/// is), and counts the tiles it ran.
#[derive(Debug)]
pub struct NetworkPredictor<'a> {
    net: &'a IvpNet,
    coverage: Coverage,
    factor: usize,
    tiles_run: AtomicUsize,
    dense_passes: AtomicUsize,
    pixels_read: AtomicUsize,
}

impl<'a> NetworkPredictor<'a> {
    pub fn new(net: &'a IvpNet, coverage: Coverage, factor: usize) -> Self {
        Self {
            net,
            coverage,
            factor: factor.max(1),
            tiles_run: AtomicUsize::new(0),
            dense_passes: AtomicUsize::new(0),
            pixels_read: AtomicUsize::new(0),
        }
    }

    /// Pixels of the (shrunk) frame the network read so far, over every call: the tiles' inputs,
    /// or the whole frame for each dense pass.
    pub fn pixels_read(&self) -> usize {
        self.pixels_read.load(Ordering::Relaxed)
    }

    /// Tiles run through the network so far, over every call (0 in dense passes).
    pub fn tiles_run(&self) -> usize {
        self.tiles_run.load(Ordering::Relaxed)
    }

    /// Sparse calls that ran densely because the tiles would have cost more.
    pub fn dense_passes(&self) -> usize {
        self.dense_passes.load(Ordering::Relaxed)
    }

    /// The network's vectors on `tiles` of `frame`, written at the full-size pixels to predict;
    /// also how many of those got a NaN or infinite vector.
    fn run_tiles(&self, frame: &NetworkFrame<'_>, tiles: &[Tile], out: &mut VectorField) -> candle_core::Result<usize> {
        // Tiles of one input size share a batch; a BTreeMap keeps the order fixed.
        let mut by_size: BTreeMap<(usize, usize), Vec<&Tile>> = BTreeMap::new();
        for tile in tiles {
            by_size.entry((tile.input.width, tile.input.height)).or_default().push(tile);
        }
        let batches: Vec<&[&Tile]> = by_size.values().flat_map(|group| group.chunks(MAX_TILES_PER_BATCH)).collect();
        // Batches in parallel as well as within: the small maps of a tile's deeper layers leave
        // threads idle. Each batch's vectors do not depend on the others or on the threads.
        let predicted: Vec<candle_core::Result<Vec<f32>>> =
            batches.par_iter().map(|batch| self.run_batch(frame, batch)).collect();
        let mut non_finite = 0;
        for (batch, vectors) in batches.iter().zip(predicted) {
            let vectors = vectors?;
            let (tw, th) = (batch[0].input.width, batch[0].input.height);
            let plane = tw * th;
            for (tile, values) in batch.iter().zip(vectors.chunks_exact(2 * plane)) {
                let (a, b) = values.split_at(plane);
                for core in &tile.cores {
                    let (dx, dy) = (core.x - tile.input.x, core.y - tile.input.y);
                    let at = |u: usize, v: usize| {
                        let j = (v + dy) * tw + u + dx;
                        [a[j], b[j]]
                    };
                    non_finite += frame.write_vectors(*core, at, out);
                }
            }
        }
        Ok(non_finite)
    }

    /// The network's vectors on `batch` (tiles of one input size) at the cores' pixels to predict:
    /// maps (B, 2, H, W) of the tiles' size, zero elsewhere.
    fn run_batch(&self, frame: &NetworkFrame<'_>, batch: &[&Tile]) -> candle_core::Result<Vec<f32>> {
        let (tw, th) = (batch[0].input.width, batch[0].input.height);
        // Each tile's window of the network's inputs, stacked into one tensor per input.
        let (prior_t, depth_t, mask_t, points) = profile::timed("tile inputs", || -> candle_core::Result<_> {
            let (priors, depths): (Vec<VectorField>, Vec<DepthMap>) =
                batch.iter().map(|t| frame.window(t.input)).unzip();
            let masks: Vec<DepthMap> = batch.iter().map(|t| frame.mask(t.input)).collect();
            Ok((
                to_batch_tensor(&priors.iter().collect::<Vec<_>>())?,
                to_batch_tensor(&depths.iter().collect::<Vec<_>>())?,
                to_batch_tensor(&masks.iter().collect::<Vec<_>>())?,
                points_to_predict(frame, batch),
            ))
        })?;
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
        let values: Vec<f32> = self.net.unmasked_output_at(&input, &points)?.flatten_all()?.to_vec1()?;
        let plane = tw * th;
        let mut vectors = vec![0f32; batch.len() * 2 * plane];
        for (p, v) in points.iter().zip(values.chunks_exact(2)) {
            let at = 2 * p.image * plane + p.y * tw + p.x;
            (vectors[at], vectors[at + plane]) = (v[0], v[1]);
        }
        Ok(vectors)
    }
}

/// The pixels to predict in the cores of `batch` (tile `i` is image `i`), in the tiles' coordinates.
fn points_to_predict(frame: &NetworkFrame<'_>, batch: &[&Tile]) -> Vec<BatchPixel> {
    let width = frame.whole().width;
    let mut points = Vec::new();
    for (image, tile) in batch.iter().enumerate() {
        for core in &tile.cores {
            for y in core.y..core.y + core.height {
                let holes = &frame.holes()[y * width..][core.x..core.x + core.width];
                let row = holes.iter().enumerate().filter(|(_, &hole)| hole);
                points.extend(row.map(|(u, _)| BatchPixel {
                    image,
                    y: y - tile.input.y,
                    x: core.x + u - tile.input.x,
                }));
            }
        }
    }
    points
}

impl VectorPredictor for NetworkPredictor<'_> {
    fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
        let mut vectors = VectorField::zeros(depth.width(), depth.height());
        self.predict_into(&ScaledPrior::full_size(prior.clone()), depth, holes, &mut vectors)?;
        Ok(vectors)
    }

    /// Writes the vectors of every pixel of `holes` (each lies in a tile's core) and nothing else.
    fn predict_into(
        &self,
        prior: &ScaledPrior,
        depth: &DepthMap,
        holes: &[bool],
        vectors: &mut VectorField,
    ) -> Result<(), InfillError> {
        if !self.net.config().variant.predicts_vectors() {
            return Err(InfillError::NotVectors);
        }
        let expected = (depth.width(), depth.height());
        let hole_rows = holes.len() / depth.width().max(1);
        let sizes = [
            ("the prior", (prior.width(), prior.height())),
            ("the vector field", (vectors.width(), vectors.height())),
            ("the hole mask", if holes.len() == depth.len() { expected } else { (depth.width(), hole_rows) }),
        ];
        if let Some(&(what, found)) = sizes.iter().find(|(_, found)| *found != expected) {
            return Err(InfillError::SizeMismatch { what, found, expected });
        }
        let frame = NetworkFrame::new(prior, depth, holes, self.factor);
        let whole = frame.whole();
        let dense = || vec![Tile { input: whole, cores: vec![whole] }];
        let tiles = match self.coverage {
            Coverage::Dense => dense(),
            Coverage::Sparse(shape) => {
                let tiles = plan_tiles(whole.width, whole.height, frame.holes(), shape.shrunk_by(self.factor));
                if tiles.iter().map(|t| t.input.area()).sum::<usize>() >= whole.area() {
                    self.dense_passes.fetch_add(1, Ordering::Relaxed);
                    dense()
                } else {
                    self.tiles_run.fetch_add(tiles.len(), Ordering::Relaxed);
                    tracing::debug!(
                        tiles = tiles.len(),
                        read = tiles.iter().map(|t| t.input.area()).sum::<usize>(),
                        cores = tiles.iter().flat_map(|t| &t.cores).map(Rect::area).sum::<usize>(),
                        frame = whole.area(),
                        sizes = ?tiles.iter().map(|t| (t.input.width, t.input.height)).collect::<Vec<_>>(),
                        "sparse pass"
                    );
                    tiles
                }
            }
        };
        self.pixels_read.fetch_add(tiles.iter().map(|t| t.input.area()).sum(), Ordering::Relaxed);
        let count = self.run_tiles(&frame, &tiles, vectors)?;
        if count > 0 {
            let total = holes.iter().filter(|&&h| h).count();
            return Err(InfillError::NonFiniteVectors { count, total });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::model::{ModelConfig, Variant};

    /// A frame with two hole patches, one touching the right border.
    fn frame(w: usize, h: usize) -> (VectorField, DepthMap, Vec<bool>) {
        let holes: Vec<bool> =
            (0..w * h).map(|i| matches!((i % w, i / w), (20..=27, 30..=60) | (150..=159, 5..=12))).collect();
        let prior = VectorField::from_fn(w, h, |u, v| [((u * 7 + v) % 13) as f32 * 0.3 - 2.0, (v % 5) as f32 * 0.4]);
        let depth = DepthMap::from_fn(w, h, |u, v| [if holes[v * w + u] { 0.0 } else { 1.0 + (u as f32 * 0.05) }]);
        (prior, depth, holes)
    }

    fn sparse(net: &IvpNet, core: usize, margin: usize, factor: usize) -> NetworkPredictor<'_> {
        NetworkPredictor::new(net, Coverage::Sparse(TileShape::new(core, margin).unwrap()), factor)
    }

    fn largest_difference(a: &VectorField, b: &VectorField) -> f32 {
        a.as_flat().iter().zip(b.as_flat()).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max)
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
        let total = holes.iter().filter(|&&h| h).count();
        let err = net.predict(&prior, &depth, &holes).unwrap_err().to_string();
        assert!(err.contains(&format!("{total} of {total} hole pixels got non-finite vectors")), "{err}");
        for factor in [1, 2] {
            let tiled = sparse(&net, 32, 80, factor);
            let err = tiled.predict(&prior, &depth, &holes).unwrap_err().to_string();
            assert!(tiled.tiles_run() > 0, "the sparse path must be the one tested");
            assert!(err.contains("non-finite vectors"), "{err}");
        }
    }

    #[test]
    fn tiles_with_a_margin_beyond_the_receptive_field_match_a_dense_pass() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        let (w, h) = (480, 320);
        let (prior, depth, holes) = frame(w, h);
        for factor in [1, 2] {
            let dense = NetworkPredictor::new(&net, Coverage::Dense, factor).predict(&prior, &depth, &holes).unwrap();
            // The U-Net and depth head together see about 70 pixels on each side.
            let tiled = sparse(&net, 32, 80, factor);
            let vectors = tiled.predict(&prior, &depth, &holes).unwrap();
            assert!(tiled.tiles_run() > 0 && tiled.dense_passes() == 0);
            let worst = largest_difference(&dense, &vectors);
            assert!(worst < 1e-4, "factor {factor}: largest difference {worst}");
            assert!(vectors.pixels().iter().zip(&holes).all(|(v, &hole)| hole || *v == [0.0, 0.0]));
            assert!(vectors.pixels().iter().zip(&holes).filter(|(_, &hole)| hole).all(|(v, _)| *v != [0.0, 0.0]));
            // Without context the tiles do differ: the comparison above can fail.
            let blind = sparse(&net, 32, 0, factor).predict(&prior, &depth, &holes).unwrap();
            let worst = largest_difference(&dense, &blind);
            assert!(
                worst > 1e-2,
                "factor {factor}: a margin of 0 should change the vectors, largest difference {worst}"
            );
        }
        // A dense pass at factor 1 is the network on the whole frame.
        let dense = NetworkPredictor::new(&net, Coverage::Dense, 1).predict(&prior, &depth, &holes).unwrap();
        assert_eq!(dense, net.predict(&prior, &depth, &holes).unwrap());
    }

    #[test]
    fn all_hole_frames_run_densely_and_results_do_not_depend_on_threads() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 6).unwrap();
        let (w, h) = (96, 80);
        let (prior, depth, _) = frame(w, h);
        let all = vec![true; w * h];
        let tiled = NetworkPredictor::new(&net, Coverage::default(), 1);
        let out = tiled.predict(&prior, &depth, &all).unwrap();
        assert_eq!((tiled.dense_passes(), tiled.tiles_run()), (1, 0));
        assert_eq!(out, NetworkPredictor::new(&net, Coverage::Dense, 1).predict(&prior, &depth, &all).unwrap());

        let (w, h) = (176, 96);
        let (prior, depth, holes) = frame(w, h);
        for factor in [1, 2] {
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                pool.install(|| sparse(&net, 32, 16, factor).predict(&prior, &depth, &holes)).unwrap()
            };
            assert_eq!(run(1), run(3), "factor {factor}");
        }
    }

    #[test]
    fn a_network_shrunk_to_a_few_pixels_still_fills_every_hole() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        // 37 x 23 pixels at factor 16: 3 x 2 blocks, one of them holding the whole hole.
        let (w, h) = (37, 23);
        let holes: Vec<bool> = (0..w * h).map(|i| (10..14).contains(&(i % w)) && (5..9).contains(&(i / w))).collect();
        let depth = DepthMap::from_fn(w, h, |u, v| [if holes[v * w + u] { 0.0 } else { 3.0 + u as f32 }]);
        let prior = VectorField::zeros(w, h);
        for factor in [16, 40] {
            for coverage in [Coverage::Dense, Coverage::default()] {
                let vectors = NetworkPredictor::new(&net, coverage, factor).predict(&prior, &depth, &holes).unwrap();
                assert_eq!((vectors.width(), vectors.height()), (w, h));
                for (i, v) in vectors.pixels().iter().enumerate() {
                    assert!(v.iter().all(|x| x.is_finite()), "factor {factor}, pixel {i}: {v:?}");
                    assert_eq!(*v == [0.0, 0.0], !holes[i], "factor {factor}, pixel {i}: {v:?}");
                }
            }
        }
    }

    #[test]
    fn predicting_into_a_used_field_writes_the_holes_only() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        let (w, h) = (480, 320);
        let (prior, depth, holes) = frame(w, h);
        let stale = |u: usize, v: usize| [u as f32, -(v as f32)];
        for (coverage, factor) in [(Coverage::Dense, 1), (Coverage::default(), 1), (Coverage::default(), 2)] {
            let predictor = NetworkPredictor::new(&net, coverage, factor);
            let fresh = predictor.predict(&prior, &depth, &holes).unwrap();
            let mut used = VectorField::from_fn(w, h, stale);
            let prior = ScaledPrior::full_size(prior.clone());
            predictor.predict_into(&prior, &depth, &holes, &mut used).unwrap();
            for (i, (got, want)) in used.pixels().iter().zip(fresh.pixels()).enumerate() {
                let expected = if holes[i] { *want } else { stale(i % w, i / w) };
                assert_eq!(*got, expected, "{coverage:?} factor {factor}, pixel {i}");
            }
            let mut wrong_size = VectorField::zeros(w, h - 1);
            assert!(predictor.predict_into(&prior, &depth, &holes, &mut wrong_size).is_err());
        }
    }

    #[test]
    fn the_intensity_variant_is_refused() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Intensity, 0.125), 1).unwrap();
        let (prior, depth, holes) = frame(176, 96);
        for coverage in [Coverage::Dense, Coverage::default()] {
            assert!(NetworkPredictor::new(&net, coverage, 1).predict(&prior, &depth, &holes).is_err());
        }
    }
}
