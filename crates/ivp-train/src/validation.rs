//! The fixed validation set of a run: crops from the validation stream (never seen in training),
//! infilled the way `ivp eval` does it (iterative infilling, ALGORITHMS.md §6.5) and scored with the metrics
//! of ALGORITHMS.md §7, next to the `fill` baseline on the same crops.

use std::sync::Arc;

use anyhow::Result;
use ivp_core::inference::{infill_frame, FrameInputs};
use ivp_core::infill::fill_disocclusions_background;
use ivp_core::metrics::score_frame;
use ivp_core::nn::model::IvpNet;
use ivp_core::{HoleMask, PixelClass, RgbImage};
use ivp_data::samples::{ClipSource, Sample, SampleConfig, SampleGenerator, Split};
use rayon::prelude::*;

/// D-MSE (0..255 scale) and D-SSIM averaged over the validation crops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidationScores {
    pub d_mse: f64,
    pub d_ssim: f64,
}

pub struct ValidationSet {
    samples: Vec<Sample>,
    holes: Vec<HoleMask>,
}

impl ValidationSet {
    /// The first `count` samples of the validation stream of `source` (a function of the seed and
    /// crop size alone).
    pub fn new(source: Arc<dyn ClipSource>, config: SampleConfig, count: usize) -> Result<Self> {
        let generator = SampleGenerator::new(source, config, Split::Validation)?;
        let mut samples = Vec::with_capacity(count);
        let mut step = 0;
        while samples.len() < count {
            samples.extend(generator.samples(step)?.into_iter().take(count - samples.len()));
            step += 1;
        }
        let holes = samples.iter().map(hole_mask).collect();
        Ok(Self { samples, holes })
    }

    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The `fill` baseline on the same crops.
    pub fn score_fill(&self) -> ValidationScores {
        self.score(|i| {
            let (s, holes) = (&self.samples[i], &self.holes[i]);
            let mut image = s.warped.clone();
            fill_disocclusions_background(&mut image, &s.warped_depth, holes);
            Ok(image)
        })
        .expect("fill cannot fail")
    }

    /// The network with `iterations` of test-time infilling.
    pub fn score_network(&self, net: &IvpNet, iterations: usize) -> Result<ValidationScores> {
        self.score(|i| {
            let (s, holes) = (&self.samples[i], &self.holes[i]);
            let inputs = FrameInputs {
                warped: &s.warped,
                warped_depth: &s.warped_depth,
                holes,
                prior: &s.prior,
                last: Some(&s.last),
                last_warped: Some(&s.last_warped),
            };
            Ok(infill_frame(net, &inputs, iterations)?)
        })
    }

    /// Mean D-MSE and D-SSIM of the predictions of `predict` (by sample index) over the crops that
    /// have disocclusions (every validation crop is centred on one).
    fn score(&self, predict: impl Fn(usize) -> Result<RgbImage> + Sync) -> Result<ValidationScores> {
        let scores = (0..self.samples.len())
            .into_par_iter()
            .map(|i| {
                let prediction = predict(i)?.quantized_to_8bit();
                Ok(score_frame(&prediction, &self.samples[i].truth, &self.holes[i].disocclusions()))
            })
            .collect::<Result<Vec<_>>>()?;
        let (mut d_mse, mut d_ssim, mut n) = (0.0, 0.0, 0usize);
        for s in &scores {
            if let (Some(m), Some(q)) = (s.d_mse, s.d_ssim) {
                d_mse += m;
                d_ssim += q;
                n += 1;
            }
        }
        let n = n.max(1) as f64;
        Ok(ValidationScores { d_mse: d_mse / n, d_ssim: d_ssim / n })
    }
}

/// The holes of a sample's warp: disocclusions from its mask, new regions where the warp left no
/// depth and there is no disocclusion.
pub fn hole_mask(sample: &Sample) -> HoleMask {
    let classes = sample
        .mask
        .as_flat()
        .iter()
        .zip(sample.warped_depth.as_flat())
        .map(|(&m, &z)| {
            if m > 0.5 {
                PixelClass::Disocclusion
            } else if z > 0.0 {
                PixelClass::Known
            } else {
                PixelClass::NewRegion
            }
        })
        .collect();
    HoleMask::from_classes(sample.size(), sample.size(), classes)
}
