//! A batch of samples as candle tensors (CPU, f32, NCHW).

use candle_core::Tensor;
use ivp_core::nn::tensor::to_batch_tensor;
use ivp_core::Image;

use super::sample::{Sample, SampleOrigin};

/// The samples of one training step, stacked. Every tensor is `(B, C, H, W)`, f32, on the CPU.
#[derive(Clone, Debug)]
pub struct Batch {
    /// The step this batch belongs to.
    pub step: u64,
    /// Temporal prior `(alpha^w, beta^w)`: `(B, 2, H, W)`.
    pub prior: Tensor,
    /// Warped depth `d^w_t`: `(B, 1, H, W)`, 0 in holes.
    pub warped_depth: Tensor,
    /// Warped frame `f^w_t`: `(B, 3, H, W)`.
    pub warped: Tensor,
    /// Disocclusions of the warp `n -> t`: `(B, 1, H, W)`, 1.0 on disocclusions, else 0.0.
    pub mask: Tensor,
    /// Ground truth `f_t`: `(B, 3, H, W)`.
    pub truth: Tensor,
    /// Last rendered frame `f_n`: `(B, 3, H, W)`.
    pub last: Tensor,
    /// `f^w_n`, frame `n - 2` warped into view `n`: `(B, 3, H, W)`.
    pub last_warped: Tensor,
    /// Where each sample came from, in batch order.
    pub origins: Vec<SampleOrigin>,
}

impl Batch {
    /// Stacks samples of one crop size. Panics if `samples` is empty or sizes differ.
    pub fn from_samples(step: u64, samples: &[Sample]) -> Self {
        assert!(!samples.is_empty(), "a batch needs at least one sample");
        let size = samples[0].size();
        assert!(samples.iter().all(|s| s.size() == size), "samples of different crop sizes");
        Self {
            step,
            prior: stack(samples, |s| &s.prior),
            warped_depth: stack(samples, |s| &s.warped_depth),
            warped: stack(samples, |s| &s.warped),
            mask: stack(samples, |s| &s.mask),
            truth: stack(samples, |s| &s.truth),
            last: stack(samples, |s| &s.last),
            last_warped: stack(samples, |s| &s.last_warped),
            origins: samples.iter().map(|s| s.origin.clone()).collect(),
        }
    }

    /// Samples in the batch.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }
}

/// One field of every sample as a `(B, C, H, W)` tensor.
fn stack<const C: usize>(samples: &[Sample], field: impl Fn(&Sample) -> &Image<C>) -> Tensor {
    let images: Vec<&Image<C>> = samples.iter().map(field).collect();
    to_batch_tensor(&images).expect("the samples of a batch share one crop size")
}
