//! Neural-network operators for candle that are faster on CPU than candle's own.

pub mod at_points;
pub mod conv2d;
pub mod gaussian;
pub mod profile;
pub mod resize;
pub mod sampler;
pub mod upsampled_conv;

pub use conv2d::{conv2d, conv2d_relu};
pub use gaussian::gaussian_blur;
pub use resize::{upsample_bilinear_to, upsample_concat, upsample_nearest2x_to};
pub use sampler::sample_bilinear;

use candle_core::{bail, CpuStorage, Layout, Result};

/// The f32 values of a contiguous tensor's storage; `op` names the caller in the error.
fn contiguous_values<'a>(s: &'a CpuStorage, l: &Layout, op: &str) -> Result<&'a [f32]> {
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&s.as_slice::<f32>()?[a..b]),
        None => bail!("{op}: contiguous tensors expected"),
    }
}

/// Helpers shared by the operators' tests.
#[cfg(test)]
pub(crate) mod test_util {
    use candle_core::{Device, Tensor};

    /// Deterministic values in [-1, 1) (candle cannot seed its CPU generator).
    pub fn random(shape: &[usize], seed: u64) -> Tensor {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let n = shape.iter().product();
        let v: Vec<f32> = (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
            })
            .collect();
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    pub fn flat(t: &Tensor) -> Vec<f32> {
        t.flatten_all().unwrap().to_vec1().unwrap()
    }

    pub fn tensor(v: Vec<f32>, shape: &[usize]) -> Tensor {
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    /// The central differences of `loss` at `base` along each coordinate, with step `eps`.
    pub fn central_differences(base: &[f32], eps: f32, loss: impl Fn(Vec<f32>) -> f64) -> Vec<f64> {
        let at = |i: usize, d: f32| {
            let mut v = base.to_vec();
            v[i] += d;
            loss(v)
        };
        (0..base.len()).map(|i| (at(i, eps) - at(i, -eps)) / (2.0 * eps as f64)).collect()
    }

    /// Asserts `|fd - analytic| < tol (1 + |fd|)` at every coordinate; `what` names the case.
    pub fn assert_matches_differences(analytic: &[f32], differences: &[f64], tol: f64, what: &str) {
        assert_eq!(analytic.len(), differences.len(), "{what}");
        for (i, (&a, &fd)) in analytic.iter().zip(differences).enumerate() {
            assert!((fd - a as f64).abs() < tol * (1.0 + fd.abs()), "{what} [{i}]: {a} vs {fd}");
        }
    }
}
