//! The fixed validation set of a run: crops from the validation stream (never seen in training),
//! infilled the way `ivp eval` does it (iterative infilling, ALGORITHMS.md §6.5) and scored with the metrics
//! of ALGORITHMS.md §7, next to the `fill` baseline on the same crops. In data-parallel training each rank
//! holds and scores its part of the set, and every rank gets the scores of the whole set.

use std::ops::Range;
use std::sync::Arc;

use anyhow::Result;
use ivp_core::inference::{infill_frame, FrameInputs};
use ivp_core::infill::fill_disocclusions_background;
use ivp_core::metrics::score_frame;
use ivp_core::nn::model::IvpNet;
use ivp_core::prior::ScaledPrior;
use ivp_core::{HoleMask, PixelClass, RgbImage};
use ivp_data::samples::{ClipSource, Sample, SampleConfig, SampleGenerator, Split};
use rayon::prelude::*;

use crate::distributed::{even_part, ProcessGroup};

/// D-MSE (0..255 scale) and D-SSIM averaged over the validation crops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidationScores {
    pub d_mse: f64,
    pub d_ssim: f64,
}

/// The validation set of a run, or one rank's part of it.
pub struct ValidationSet {
    /// Samples `part` of the set.
    samples: Vec<Sample>,
    holes: Vec<HoleMask>,
    /// Samples in the whole set.
    count: usize,
}

impl ValidationSet {
    /// The first `count` samples of the validation stream of `source` (a function of the seed and
    /// crop size alone); `group`'s rank holds its part of them ([`even_part`]).
    pub fn new(
        source: Arc<dyn ClipSource>,
        config: SampleConfig,
        count: usize,
        group: &dyn ProcessGroup,
    ) -> Result<Self> {
        let batch = config.batch_size;
        let generator = SampleGenerator::new(source, config, Split::Validation)?;
        let part: Range<usize> = even_part(count, group.rank(), group.size());
        // Sample i of the set is sample i % batch of batch i / batch of the stream.
        let samples = part.map(|i| generator.sample((i / batch) as u64, i % batch)).collect::<Result<Vec<_>, _>>()?;
        let holes = samples.iter().map(hole_mask).collect();
        Ok(Self { samples, holes, count })
    }

    /// Samples in the whole set.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The `fill` baseline on the same crops.
    pub fn score_fill(&self, group: &dyn ProcessGroup) -> ValidationScores {
        self.score(group, |i| {
            let (s, holes) = (&self.samples[i], &self.holes[i]);
            let mut image = s.warped.clone();
            fill_disocclusions_background(&mut image, &s.warped_depth, holes);
            Ok(image)
        })
        .expect("fill cannot fail")
    }

    /// The network with `iterations` of test-time infilling.
    pub fn score_network(&self, net: &IvpNet, iterations: usize, group: &dyn ProcessGroup) -> Result<ValidationScores> {
        self.score(group, |i| {
            let (s, holes) = (&self.samples[i], &self.holes[i]);
            let prior = ScaledPrior::full_size(s.prior.clone());
            let inputs = FrameInputs {
                warped: &s.warped,
                warped_depth: &s.warped_depth,
                holes,
                prior: &prior,
                last: Some(&s.last),
                last_warped: Some(&s.last_warped),
            };
            Ok(infill_frame(net, &inputs, iterations)?)
        })
    }

    /// Mean D-MSE and D-SSIM of the predictions of `predict` (by index into this rank's samples)
    /// over the crops of the whole set that have disocclusions (every validation crop is centred on
    /// one), added in the order of the set whatever the number of ranks.
    fn score(
        &self,
        group: &dyn ProcessGroup,
        predict: impl Fn(usize) -> Result<RgbImage> + Sync,
    ) -> Result<ValidationScores> {
        let scores = (0..self.samples.len())
            .into_par_iter()
            .map(|i| {
                let prediction = predict(i)?.quantized_to_8bit();
                let s = score_frame(&prediction, &self.samples[i].truth, &self.holes[i].disocclusions());
                Ok(s.d_mse.zip(s.d_ssim))
            })
            .collect::<Result<Vec<_>>>()?;
        let (mut d_mse, mut d_ssim, mut n) = (0.0, 0.0, 0usize);
        for (m, q) in gather_scores(group, self.count, &scores).into_iter().flatten() {
            d_mse += m;
            d_ssim += q;
            n += 1;
        }
        let n = n.max(1) as f64;
        Ok(ValidationScores { d_mse: d_mse / n, d_ssim: d_ssim / n })
    }
}

/// Every rank's `(D-MSE, D-SSIM)` of its part of a set of `count` samples, in the order of the set.
fn gather_scores(group: &dyn ProcessGroup, count: usize, part: &[Option<(f64, f64)>]) -> Vec<Option<(f64, f64)>> {
    if group.size() == 1 {
        return part.to_vec();
    }
    // Parts differ in length by one at most: each is sent padded to the longest, as
    // (has a score, D-MSE, D-SSIM) per sample.
    let longest = even_part(count, 0, group.size()).len();
    let mut values = vec![0.0; 3 * longest];
    for (slot, score) in values.chunks_exact_mut(3).zip(part) {
        if let Some((m, q)) = score {
            slot.copy_from_slice(&[1.0, *m, *q]);
        }
    }
    let all = group.all_gather(&values);
    (0..group.size())
        .flat_map(|rank| {
            let samples = even_part(count, rank, group.size()).len();
            all[rank * 3 * longest..].chunks_exact(3).take(samples).map(|s| (s[0] == 1.0).then_some((s[1], s[2])))
        })
        .collect()
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
