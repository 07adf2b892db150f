//! A trained network at test time, on images: the [`VectorPredictor`] behind the iterative
//! infilling (ALGORITHMS.md §6.5), and [`ModelInfiller`], the network as an [`Infiller`] beside the
//! classical methods.
//!
//! Layer: the top of the crate; the one place where `nn` meets `infill` and `prior`.

pub mod predictor;
pub mod scaled;
pub mod tiles;

pub use predictor::{Coverage, NetworkPredictor};
pub use scaled::{NetworkFrame, PriorScale, Scale};
pub use tiles::{plan_tiles, Tile, TileShape};

use std::time::{Duration, Instant};

use candle_core::{Device, Tensor};

use crate::geometry::{DepthMap, HoleMask, PixelClass, RgbImage, VectorField};
use crate::infill::iterative::{infill_iteratively, InfillRules, VectorPredictor};
use crate::infill::rules::fill_new_regions;
use crate::infill::{InfillContext, InfillError, Infilled, Infiller};
use crate::nn::model::{IvpNet, NetInput, Variant};
use crate::nn::tensor::{from_tensor, to_tensor};
use crate::prior::{scaled_target_prior, warp_to_last, ScaledPrior};

/// One frame's inputs to a network at test time.
#[derive(Clone, Copy, Debug)]
pub struct FrameInputs<'a> {
    /// `f^w_{n+1}`, 0 in holes.
    pub warped: &'a RgbImage,
    /// `d^w_{n+1}`, 0 in holes.
    pub warped_depth: &'a DepthMap,
    pub holes: &'a HoleMask,
    /// The temporal prior (zeros when there is none), at the scale it was measured on.
    pub prior: &'a ScaledPrior,
    /// `f_n` and `f^w_n`: read by the intensity variant only (zeros when absent).
    pub last: Option<&'a RgbImage>,
    pub last_warped: Option<&'a RgbImage>,
}

/// What a network predicted for one frame.
#[derive(Clone, Debug)]
pub struct ModelPrediction {
    pub image: RgbImage,
    /// The vectors each disocclusion pixel was filled with (`None` for the intensity variant).
    pub vectors: Option<VectorField>,
    /// Time by stage: `"prior"`, `"network"`, `"infill"`.
    pub stages: Vec<(&'static str, Duration)>,
    /// Tiles the network ran on, over every iteration (0 when it ran densely).
    pub tiles: usize,
    /// Pixels of the frame the network saw (shrunk, at a scale factor above 1) that it read over
    /// every iteration: its tiles' inputs, or the whole frame per dense pass.
    pub pixels_read: usize,
}

/// The network in one dense pass over the frame as it is.
impl VectorPredictor for IvpNet {
    fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
        NetworkPredictor::new(self, Coverage::Dense, 1).predict(prior, depth, holes)
    }
}

/// The frame predicted by `net` in dense passes: iterative infilling with `iterations` for the
/// vector variants, one pass for the intensity variant; new regions by the common rule.
pub fn infill_frame(net: &IvpNet, inputs: &FrameInputs<'_>, iterations: usize) -> Result<RgbImage, InfillError> {
    Ok(predict_frame(net, inputs, iterations, InfillRules::default(), Coverage::Dense, 1)?.image)
}

/// What [`predict_frame`] gives besides the image.
struct FramePrediction {
    image: RgbImage,
    vectors: Option<VectorField>,
    network_time: Duration,
    /// Tiles run through the network over every iteration (0 in dense passes).
    tiles: usize,
    /// Pixels the network read over every iteration.
    pixels_read: usize,
}

/// [`infill_frame`] with any coverage and scale factor (vector variants only), the vectors used,
/// the time inside the network and the tiles run.
fn predict_frame(
    net: &IvpNet,
    inputs: &FrameInputs<'_>,
    iterations: usize,
    rules: InfillRules,
    coverage: Coverage,
    factor: usize,
) -> Result<FramePrediction, InfillError> {
    let (warped, depth, holes, prior) = (inputs.warped, inputs.warped_depth, inputs.holes, inputs.prior);
    if net.config().variant.predicts_vectors() {
        let predictor = NetworkPredictor::new(net, coverage, factor);
        let out = infill_iteratively(&predictor, warped, depth, holes, prior, iterations, rules)?;
        let (tiles, pixels_read) = (predictor.tiles_run(), predictor.pixels_read());
        tracing::debug!(
            factor,
            thin_runs = out.thin_runs,
            filled_per_iteration = ?out.filled_per_iteration,
            walked = out.walked,
            fell_back = out.fell_back,
            foreground_reads = out.foreground_reads,
            "iterative infilling"
        );
        return Ok(FramePrediction {
            image: out.image,
            vectors: Some(out.vectors),
            network_time: out.predict_time,
            tiles,
            pixels_read,
        });
    }
    let started = Instant::now();
    let image = predict_intensity(net, inputs)?;
    let pixels_read = inputs.warped.len();
    Ok(FramePrediction { image, vectors: None, network_time: started.elapsed(), tiles: 0, pixels_read })
}

/// The intensity variant: the network's colours on the disocclusions, the warp elsewhere.
fn predict_intensity(net: &IvpNet, inputs: &FrameInputs<'_>) -> candle_core::Result<RgbImage> {
    let (w, h) = (inputs.warped.width(), inputs.warped.height());
    let zeros = RgbImage::zeros(w, h);
    let disocclusions: Vec<f32> =
        inputs.holes.classes().iter().map(|c| f32::from(u8::from(*c == PixelClass::Disocclusion))).collect();
    let mask = Tensor::from_vec(disocclusions, (1, 1, h, w), &Device::Cpu)?;
    let (warped, depth, prior) =
        (to_tensor(inputs.warped)?, to_tensor(inputs.warped_depth)?, to_tensor(&inputs.prior.to_full())?);
    let last = to_tensor(inputs.last.unwrap_or(&zeros))?;
    let last_warped = to_tensor(inputs.last_warped.unwrap_or(&zeros))?;
    let input = NetInput {
        prior: &prior,
        warped_depth: &depth,
        mask: &mask,
        warped: &warped,
        last: Some(&last),
        last_warped: Some(&last_warped),
    };
    let mut image: RgbImage = from_tensor(&net.forward(&input)?.frame)?;
    let bad = image.as_flat().iter().filter(|c| !c.is_finite()).count();
    if bad > 0 {
        candle_core::bail!("{bad} non-finite colour values in the predicted frame (broken weights?)");
    }
    fill_new_regions(&mut image, inputs.holes);
    Ok(image)
}

/// A trained network among the infilling methods (`ivp eval --model`).
#[derive(Clone, Debug)]
pub struct ModelInfiller {
    name: String,
    net: IvpNet,
    iterations: usize,
    rules: InfillRules,
    coverage: Coverage,
    scale: Scale,
    prior_scale: PriorScale,
}

impl ModelInfiller {
    /// `iterations` is P of ALGORITHMS.md §6.5 (ignored by the intensity variant). Sparse, at
    /// the automatic scale and with the recipe's rules around the passes by default.
    pub fn new(name: impl Into<String>, net: IvpNet, iterations: usize) -> Self {
        let (rules, coverage) = (InfillRules::default(), Coverage::default());
        let (scale, prior_scale) = (Scale::default(), PriorScale::default());
        Self { name: name.into(), net, iterations, rules, coverage, scale, prior_scale }
    }

    /// The same model with other rules around the passes (the thin runs and the far blur:
    /// ALGORITHMS.md §6.5).
    pub fn with_rules(self, rules: InfillRules) -> Self {
        Self { rules, ..self }
    }

    /// The same model run at `scale` (vector variants; the intensity variant runs at full size).
    pub fn with_scale(self, scale: Scale) -> Self {
        Self { scale, ..self }
    }

    pub fn scale(&self) -> Scale {
        self.scale
    }

    /// The same model with the temporal prior measured at `prior_scale` (ALGORITHMS.md §6.7).
    pub fn with_prior_scale(self, prior_scale: PriorScale) -> Self {
        Self { prior_scale, ..self }
    }

    pub fn prior_scale(&self) -> PriorScale {
        self.prior_scale
    }

    /// The same model covering frames as `coverage` says (the intensity variant is always dense).
    pub fn with_coverage(self, coverage: Coverage) -> Self {
        Self { coverage, ..self }
    }

    pub fn coverage(&self) -> Coverage {
        self.coverage
    }

    pub fn net(&self) -> &IvpNet {
        &self.net
    }

    /// The prediction for a context, with the vectors used (ALGORITHMS.md §6.5).
    pub fn predict(&self, ctx: &InfillContext<'_>) -> Result<ModelPrediction, InfillError> {
        let warped = ctx.warped;
        let (w, h) = (warped.image.width(), warped.image.height());
        let started = Instant::now();
        let variant = self.net.config().variant;
        let factor = self.scale.factor(h);
        let prior_factor = self.prior_scale.factor(factor);
        // The prior is measured on frame n-2; without it (first frames) the model runs without.
        let (prior, last_warped) = match variant {
            Variant::Full | Variant::NoDepth => {
                let prior = ctx.before_last.as_ref().map(|before_last| {
                    scaled_target_prior(
                        before_last,
                        &ctx.last,
                        ctx.target_pose,
                        ctx.intrinsics,
                        &ctx.warped.holes,
                        prior_factor,
                    )
                });
                (prior, None)
            }
            Variant::Intensity => {
                (None, ctx.before_last.as_ref().map(|b| warp_to_last(b, &ctx.last, ctx.intrinsics).image))
            }
            Variant::NoTemporalPrior => (None, None),
        };
        let prior = prior.unwrap_or_else(|| ScaledPrior::zeros(w, h, prior_factor));
        let prior_time = started.elapsed();
        let inputs = FrameInputs {
            warped: &warped.image,
            warped_depth: &warped.depth,
            holes: &warped.holes,
            prior: &prior,
            last: Some(ctx.last.image),
            last_warped: last_warped.as_ref(),
        };
        let started = Instant::now();
        let out = predict_frame(&self.net, &inputs, self.iterations, self.rules, self.coverage, factor)?;
        let infill_time = started.elapsed().saturating_sub(out.network_time);
        Ok(ModelPrediction {
            image: out.image,
            vectors: out.vectors,
            stages: vec![("prior", prior_time), ("network", out.network_time), ("infill", infill_time)],
            tiles: out.tiles,
            pixels_read: out.pixels_read,
        })
    }
}

impl Infiller for ModelInfiller {
    fn name(&self) -> &str {
        &self.name
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let prediction = self.predict(ctx)?;
        Ok(Infilled { image: prediction.image, stages: prediction.stages, vectors: prediction.vectors })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::model::ModelConfig;

    #[test]
    fn the_network_predicts_vectors_only_on_holes_and_fills_every_hole() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 1).unwrap();
        let (w, h) = (23, 17);
        let classes: Vec<PixelClass> = (0..w * h)
            .map(|i| match (i % w, i / w) {
                (8..=10, 3..=12) => PixelClass::Disocclusion,
                (0, _) => PixelClass::NewRegion,
                _ => PixelClass::Known,
            })
            .collect();
        let holes = HoleMask::from_classes(w, h, classes);
        let known = holes.known();
        let warped = RgbImage::from_pixels(
            w,
            h,
            (0..w * h).map(|i| if known[i] { [0.2, 0.5, (i % w) as f32 / w as f32] } else { [0.0; 3] }).collect(),
        );
        let depth = DepthMap::from_pixels(w, h, known.iter().map(|&k| [if k { 5.0 } else { 0.0 }]).collect());
        let prior = VectorField::zeros(w, h);
        let vectors = net.predict(&prior, &depth, &holes.disocclusions()).unwrap();
        for (i, v) in vectors.pixels().iter().enumerate() {
            if !holes.disocclusions()[i] {
                assert_eq!(*v, [0.0, 0.0]);
            }
        }
        let inputs = FrameInputs {
            warped: &warped,
            warped_depth: &depth,
            holes: &holes,
            prior: &ScaledPrior::full_size(prior),
            last: None,
            last_warped: None,
        };
        let image = infill_frame(&net, &inputs, 3).unwrap();
        for (i, p) in image.pixels().iter().enumerate() {
            assert!(p.iter().all(|c| c.is_finite()));
            if known[i] {
                assert_eq!(*p, warped.pixels()[i]);
            } else {
                // Every hole takes a colour of the known part of this frame (green 0.5).
                assert!((p[1] - 0.5).abs() < 1e-5, "pixel {i}: {p:?}");
            }
        }
    }

    #[test]
    fn extreme_depths_and_all_hole_frames_give_finite_images() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 2).unwrap();
        let (w, h) = (19, 13);
        let prior = ScaledPrior::zeros(w, h, 1);
        for (label, depth_value, hole_every) in [
            ("huge depth", 1e30f32, 3),
            ("infinite depth", f32::INFINITY, 3),
            ("NaN depth", f32::NAN, 3),
            ("all holes", 5.0, 1),
        ] {
            let classes: Vec<PixelClass> = (0..w * h)
                .map(|i| if i % hole_every == 0 { PixelClass::Disocclusion } else { PixelClass::Known })
                .collect();
            let holes = HoleMask::from_classes(w, h, classes);
            let known = holes.known();
            let warped = RgbImage::from_pixels(
                w,
                h,
                known.iter().map(|&k| if k { [0.3, 0.6, 0.9] } else { [0.0; 3] }).collect(),
            );
            let depth =
                DepthMap::from_pixels(w, h, known.iter().map(|&k| [if k { depth_value } else { 0.0 }]).collect());
            let inputs = FrameInputs {
                warped: &warped,
                warped_depth: &depth,
                holes: &holes,
                prior: &prior,
                last: None,
                last_warped: None,
            };
            let image = infill_frame(&net, &inputs, 3).unwrap();
            assert!(image.pixels().iter().flatten().all(|c| c.is_finite()), "{label}");
        }
    }

    #[test]
    fn an_intensity_network_with_nan_weights_is_an_error() {
        let (net, varmap) = IvpNet::seeded(ModelConfig::new(Variant::Intensity, 0.125), 4).unwrap();
        for var in varmap.all_vars() {
            var.set(&Tensor::full(f32::NAN, var.shape(), &Device::Cpu).unwrap()).unwrap();
        }
        let scene = crate::test_scene::BoxWarp::new();
        let err = ModelInfiller::new("ivp", net, 3).predict(&scene.context(true, false)).unwrap_err().to_string();
        assert!(err.contains("non-finite colour"), "{err}");
    }

    #[test]
    fn the_model_infiller_reads_the_temporal_prior_only_in_the_variants_that_have_one() {
        let scene = crate::test_scene::BoxWarp::new();
        let (with, without) = (scene.context(true, false), scene.context(false, false));
        assert!(with.temporal_prior().unwrap().prior.as_flat().iter().any(|&x| x != 0.0));
        for (variant, reads_prior) in
            [(Variant::Full, true), (Variant::NoDepth, true), (Variant::NoTemporalPrior, false)]
        {
            let (net, _) = IvpNet::seeded(ModelConfig::new(variant, 0.125), 3).unwrap();
            let model = ModelInfiller::new("ivp", net, 3);
            let a = model.predict(&with).unwrap();
            let b = model.predict(&without).unwrap();
            let names: Vec<&str> = a.stages.iter().map(|(name, _)| *name).collect();
            assert_eq!(names, ["prior", "network", "infill"], "{variant}");
            assert_eq!(a.vectors != b.vectors, reads_prior, "{variant}");
            let infilled = model.infill(&with).unwrap();
            assert_eq!(infilled.image, a.image, "{variant}");
        }
    }
}
