//! The training losses of ALGORITHMS.md §6.4, on candle tensors and differentiable through candle's autograd:
//! `L = 1 L_mse + 1 L_ssim + 0.001 L_smooth`, each a mean over the disocclusion pixels.
//!
//! The formulas are those of the PyTorch reference (`torch_reference.py`, see tests/tests/torch_parity.rs:
//! `masked_ssim_loss`, `smoothness` and the MSE of `step()`), value for value, with one deliberate
//! difference: the SSIM term of a batch without a single disocclusion pixel is 0 (the reference
//! gives 1 there, `1 - 0 / 1`). Every term is written as `sum(term * mask) / max(count, 1)`, so an
//! empty mask gives exactly 0 and zero (finite) gradients, never NaN; with a non-empty mask it is
//! the reference's value.
//!
//! Gradients follow PyTorch's conventions at the kinks, so that the two frameworks train alike:
//! - the variance clamp `clamp_min(0)` is candle's `relu`, whose gradient is 1 at 0 as PyTorch's
//!   `clamp_min` (candle's `maximum` would give 1/2 at a tie, and `clamp` is `maximum`);
//! - `|x|` is `x * sign(x)` with the sign detached: gradient sign(x), 0 at 0 as in PyTorch (candle's
//!   `abs` backward gives +1 at 0, and costs five tensor ops instead of one);
//! - `sqrt(va vb + 1e-12)`: the 1e-12 keeps candle's `sqrt` backward (`grad / (2 sqrt)`) finite where
//!   both variances are 0.
//!
//! Reductions are candle's f32 sums; the normalising counts are exact (summed in f64 on the host,
//! the mask is data, not a parameter).
//!
//! A batch split across processes (data-parallel training) gives each part the counts of the
//! whole batch ([`LossCounts`], [`ivp_loss_normalised`]): every term is then a sum over pixels
//! divided by the whole batch's count, so the parts' losses, and their gradients, add up to the
//! whole batch's.

use candle_core::{bail, DType, Result, Tensor};

use crate::metrics::{ssim_c1, ssim_c2};
use crate::nn::ops::gaussian_blur;

/// SSIM's luminance constant for images in [0, 1]: the metric's, with `L = 1`.
const SSIM_C1: f64 = ssim_c1(1.0);
/// SSIM's contrast constant for images in [0, 1].
const SSIM_C2: f64 = ssim_c2(1.0);
/// Added under the square root of `va vb`, as in the reference; keeps the gradient finite at 0.
const SQRT_EPS: f64 = 1e-12;
/// Sharpness of the edge-aware weights `exp(-10 mean_c |grad f|)` of the smoothness term.
const EDGE_SHARPNESS: f64 = 10.0;

/// Weights of the three terms; ALGORITHMS.md §6.4: 1, 1, 0.001.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights {
    pub mse: f64,
    pub ssim: f64,
    pub smooth: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self { mse: 1.0, ssim: 1.0, smooth: 0.001 }
    }
}

/// The terms of one loss evaluation, each a scalar (0-dimensional) f32 tensor; `total` is their
/// weighted sum, the one to call `backward` on.
#[derive(Clone, Debug)]
pub struct LossTerms {
    pub mse: Tensor,
    pub ssim: Tensor,
    pub smooth: Tensor,
    pub total: Tensor,
}

/// The counts that normalise the terms: disocclusion pixels (the MSE and SSIM terms) and pairs of
/// horizontally and vertically adjacent ones (the two axes of the smoothness term).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossCounts {
    pub pixels: f64,
    pub pairs_x: f64,
    pub pairs_y: f64,
}

impl LossCounts {
    /// The counts of `mask` (B, 1, H, W), exact.
    pub fn of(mask: &Tensor) -> Result<Self> {
        Ok(Self {
            pixels: count(mask)?,
            pairs_x: count(&adjacent_pairs(mask, 3)?)?,
            pairs_y: count(&adjacent_pairs(mask, 2)?)?,
        })
    }
}

/// The loss of ALGORITHMS.md §6.4 on `prediction` and `truth` (B, 3, H, W) in [0, 1], `mask` (B, 1, H, W) of
/// 0/1 (1 on disocclusions) and the predicted `vectors` (B, 2, H, W) in pixels. Without vectors (the
/// variant that predicts intensities directly) the smoothness term is 0.
pub fn ivp_loss(
    prediction: &Tensor,
    truth: &Tensor,
    mask: &Tensor,
    vectors: Option<&Tensor>,
    weights: &LossWeights,
) -> Result<LossTerms> {
    ivp_loss_normalised(prediction, truth, mask, vectors, weights, &LossCounts::of(mask)?)
}

/// [`ivp_loss`] with every term divided by `counts` instead of the mask's own counts: the part of a
/// batch's loss that these samples contribute, when `counts` are those of the whole batch.
pub fn ivp_loss_normalised(
    prediction: &Tensor,
    truth: &Tensor,
    mask: &Tensor,
    vectors: Option<&Tensor>,
    weights: &LossWeights,
    counts: &LossCounts,
) -> Result<LossTerms> {
    check_images("ivp_loss", prediction, truth, mask)?;
    let mse = masked_mean(&squared_error(prediction, truth)?, mask, counts.pixels)?;
    let ssim = masked_mean(&ssim_loss_map(prediction, truth)?, mask, counts.pixels)?;
    let smooth = match vectors {
        Some(v) => smoothness(v, truth, mask, counts)?,
        None => Tensor::zeros((), DType::F32, prediction.device())?,
    };
    let total =
        ((mse.affine(weights.mse, 0.0)? + ssim.affine(weights.ssim, 0.0)?)? + smooth.affine(weights.smooth, 0.0)?)?;
    Ok(LossTerms { mse, ssim, smooth, total })
}

/// Mean of `(prediction - truth)^2` over the mask's pixels and the channels:
/// `sum((p - t)^2 m) / max(sum(m) C, 1)`; 0 for an empty mask.
pub fn masked_mse_loss(prediction: &Tensor, truth: &Tensor, mask: &Tensor) -> Result<Tensor> {
    check_images("masked_mse_loss", prediction, truth, mask)?;
    masked_mean(&squared_error(prediction, truth)?, mask, count(mask)?)
}

fn squared_error(prediction: &Tensor, truth: &Tensor) -> Result<Tensor> {
    (prediction - truth)?.sqr()
}

/// `1 - SSIM` averaged over the mask's pixels and the channels, with the SSIM map of luminance and
/// contrast only (no structure term), as in the reference:
/// `s = (2 mu_a mu_b + C1)(2 sqrt(va vb + 1e-12) + C2) / ((mu_a^2 + mu_b^2 + C1)(va + vb + C2))`,
/// means and variances over the 11 x 11 Gaussian window (sigma 1.5, zero padding), variances
/// clamped at 0. Computed as `sum((1 - s) m) / max(sum(m) C, 1)`: 0 for an empty mask, the
/// reference's `1 - sum(s m) / max(sum(m) C, 1)` otherwise.
///
/// Note that the 1e-12 makes s slightly above 1 in flat regions (2e-6 / C2 ~ 0.0022 for two equal
/// constant images), so this term can be slightly negative; the reference behaves the same.
pub fn masked_ssim_loss(prediction: &Tensor, truth: &Tensor, mask: &Tensor) -> Result<Tensor> {
    check_images("masked_ssim_loss", prediction, truth, mask)?;
    masked_mean(&ssim_loss_map(prediction, truth)?, mask, count(mask)?)
}

/// `1 - s` per pixel and channel, s the SSIM map of [`masked_ssim_loss`].
fn ssim_loss_map(prediction: &Tensor, truth: &Tensor) -> Result<Tensor> {
    let (a, b) = (prediction, truth);
    let (mu_a, mu_b) = (gaussian_blur(a)?, gaussian_blur(b)?);
    let (mu_a2, mu_b2) = (mu_a.sqr()?, mu_b.sqr()?);
    let va = (gaussian_blur(&a.sqr()?)? - &mu_a2)?.relu()?;
    let vb = (gaussian_blur(&b.sqr()?)? - &mu_b2)?.relu()?;
    let luminance = (&mu_a * &mu_b)?.affine(2.0, SSIM_C1)?;
    let contrast = ((&va * &vb)? + SQRT_EPS)?.sqrt()?.affine(2.0, SSIM_C2)?;
    let denominator = (((mu_a2 + mu_b2)? + SSIM_C1)? * ((va + vb)? + SSIM_C2)?)?;
    let s = ((luminance * contrast)? / denominator)?;
    s.affine(-1.0, 1.0)
}

/// Edge-aware smoothness of `vectors` (B, 2, H, W) between neighbouring disocclusion pixels, as the
/// reference's `smoothness`: for x (and likewise y), with pairs `mx` of horizontally adjacent
/// pixels both in the mask and `wx = exp(-10 mean_c |dx truth|)`,
/// `lx = sum(wx |dx vectors| mx) / max(sum(mx), 1)` (summed over both vector components, counted
/// once per pair); the loss is `lx + ly`. 0 without any such pair.
pub fn smoothness_loss(vectors: &Tensor, truth: &Tensor, mask: &Tensor) -> Result<Tensor> {
    smoothness(vectors, truth, mask, &LossCounts::of(mask)?)
}

fn smoothness(vectors: &Tensor, truth: &Tensor, mask: &Tensor, counts: &LossCounts) -> Result<Tensor> {
    let (b, _, h, w) = truth.dims4()?;
    if vectors.dims() != [b, 2, h, w] || mask.dims() != [b, 1, h, w] {
        bail!("smoothness_loss: vectors {:?}, truth {:?}, mask {:?}", vectors.dims(), truth.dims(), mask.dims());
    }
    smoothness_along(vectors, truth, mask, 3, counts.pairs_x)?
        + smoothness_along(vectors, truth, mask, 2, counts.pairs_y)?
}

/// One axis (`dim` 3: x, 2: y) of [`smoothness_loss`], divided by `pairs_count`.
fn smoothness_along(vectors: &Tensor, truth: &Tensor, mask: &Tensor, dim: usize, pairs_count: f64) -> Result<Tensor> {
    let n = vectors.dim(dim)?;
    if n < 2 {
        return Tensor::zeros((), DType::F32, vectors.device());
    }
    let diff = |t: &Tensor| t.narrow(dim, 1, n - 1)? - t.narrow(dim, 0, n - 1)?;
    let pairs = adjacent_pairs(mask, dim)?;
    let edge = (abs(&diff(truth)?)?.mean_keepdim(1)? * -EDGE_SHARPNESS)?.exp()?;
    let weighted = abs(&diff(vectors)?)?.broadcast_mul(&(edge * &pairs)?)?;
    normalise(&weighted.sum_all()?, pairs_count)
}

/// 1 where a mask pixel and its neighbour along `dim` (3: x, 2: y) are both 1; one shorter along
/// `dim` (empty for a side of 1).
fn adjacent_pairs(mask: &Tensor, dim: usize) -> Result<Tensor> {
    let n = mask.dim(dim)?;
    if n < 2 {
        return mask.narrow(dim, 0, 0);
    }
    mask.narrow(dim, 1, n - 1)? * mask.narrow(dim, 0, n - 1)?
}

/// `|x|` whose gradient is sign(x), 0 at 0 (PyTorch's), rather than candle's +1 at 0.
pub fn abs(x: &Tensor) -> Result<Tensor> {
    x * x.sign()?.detach()
}

/// `sum(x m) / max(pixels C, 1)` for x (B, C, H, W) and m (B, 1, H, W); `pixels` is the mask's
/// count (or the whole batch's).
fn masked_mean(x: &Tensor, mask: &Tensor, pixels: f64) -> Result<Tensor> {
    let c = x.dim(1)?;
    normalise(&x.broadcast_mul(mask)?.sum_all()?, pixels * c as f64)
}

/// The number of mask pixels (the sum of the mask), exact: summed in f64.
fn count(mask: &Tensor) -> Result<f64> {
    mask.to_dtype(DType::F64)?.sum_all()?.to_scalar::<f64>()
}

/// `sum / max(n, 1)` as one f32 division, like the reference's.
fn normalise(sum: &Tensor, n: f64) -> Result<Tensor> {
    sum.broadcast_div(&Tensor::new(n.max(1.0) as f32, sum.device())?)
}

fn check_images(name: &str, prediction: &Tensor, truth: &Tensor, mask: &Tensor) -> Result<()> {
    let (b, _, h, w) = prediction.dims4()?;
    if truth.dims() != prediction.dims() || mask.dims() != [b, 1, h, w] {
        bail!("{name}: prediction {:?}, truth {:?}, mask {:?}", prediction.dims(), truth.dims(), mask.dims());
    }
    if prediction.dtype() != DType::F32 || truth.dtype() != DType::F32 || mask.dtype() != DType::F32 {
        bail!("{name}: f32 tensors expected");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::{central_differences, flat, random, tensor};
    use candle_core::{Device, Var};

    /// Deterministic values in [0, 1).
    fn uniform(shape: &[usize], seed: u64) -> Tensor {
        ((random(shape, seed) + 1.0).unwrap() * 0.5).unwrap()
    }

    /// A deterministic 0/1 mask (B, 1, H, W), 1 with probability about `p`.
    fn holes(b: usize, h: usize, w: usize, p: f64, seed: u64) -> Tensor {
        uniform(&[b, 1, h, w], seed).lt(p).unwrap().to_dtype(DType::F32).unwrap()
    }

    fn scalar(t: &Tensor) -> f32 {
        assert_eq!(t.rank(), 0, "{:?}", t.dims());
        t.to_scalar::<f32>().unwrap()
    }

    fn all_finite(t: &Tensor) -> bool {
        flat(t).iter().all(|v| v.is_finite())
    }

    /// The terms and the gradients of the total with respect to the prediction and the vectors.
    fn evaluate(p: &Tensor, t: &Tensor, m: &Tensor, v: &Tensor, weights: &LossWeights) -> (LossTerms, Tensor, Tensor) {
        let (p, v) = (Var::from_tensor(p).unwrap(), Var::from_tensor(v).unwrap());
        let terms = ivp_loss(&p, t, m, Some(&v), weights).unwrap();
        let grads = terms.total.backward().unwrap();
        // No gradient entry at all for an input the total does not depend on (vectors of a 1x1 image).
        let grad = |x: &Var| grads.get(x).cloned().unwrap_or_else(|| x.zeros_like().unwrap());
        let (gp, gv) = (grad(&p), grad(&v));
        (terms, gp, gv)
    }

    const SHAPE: [usize; 4] = [2, 3, 19, 23];

    #[test]
    fn default_weights() {
        assert_eq!(LossWeights::default(), LossWeights { mse: 1.0, ssim: 1.0, smooth: 0.001 });
    }

    #[test]
    fn empty_mask_gives_zero_terms_and_finite_gradients() {
        let [b, c, h, w] = SHAPE;
        let (p, t) = (uniform(&SHAPE, 1), uniform(&SHAPE, 2));
        let v = (random(&[b, 2, h, w], 3) * 5.0).unwrap();
        let m = Tensor::zeros((b, 1, h, w), DType::F32, &Device::Cpu).unwrap();
        let (terms, gp, gv) = evaluate(&p, &t, &m, &v, &LossWeights::default());
        for (name, term) in
            [("mse", &terms.mse), ("ssim", &terms.ssim), ("smooth", &terms.smooth), ("total", &terms.total)]
        {
            assert_eq!(scalar(term), 0.0, "{name}");
        }
        assert_eq!(gp.dims(), [b, c, h, w]);
        assert!(flat(&gp).iter().chain(&flat(&gv)).all(|g| *g == 0.0));
    }

    #[test]
    fn an_image_without_holes_contributes_nothing() {
        // Image 0 of the batch has no hole: the batch's terms are those of image 1 alone.
        let [_, _, h, w] = SHAPE;
        let (p, t) = (uniform(&SHAPE, 4), uniform(&SHAPE, 5));
        let v = (random(&[2, 2, h, w], 6) * 3.0).unwrap();
        let m1 = holes(1, h, w, 0.3, 7);
        let m = Tensor::cat(&[&m1.zeros_like().unwrap(), &m1], 0).unwrap();
        let one = |x: &Tensor| x.narrow(0, 1, 1).unwrap();
        let weights = LossWeights::default();
        let both = ivp_loss(&p, &t, &m, Some(&v), &weights).unwrap();
        let alone = ivp_loss(&one(&p), &one(&t), &m1, Some(&one(&v)), &weights).unwrap();
        for (a, b) in [(&both.mse, &alone.mse), (&both.ssim, &alone.ssim), (&both.smooth, &alone.smooth)] {
            assert!((scalar(a) - scalar(b)).abs() <= 1e-6 * scalar(b).abs(), "{a} vs {b}");
            assert!(scalar(b) > 0.0);
        }
    }

    #[test]
    fn parts_of_a_batch_normalised_by_its_counts_add_up_to_the_whole() {
        // A batch of 3 split as [0, 1) and [1, 3), each part divided by the whole batch's counts
        // (data-parallel training): the parts' terms and gradients sum to the whole batch's.
        let [_, c, h, w] = SHAPE;
        let shape = [3, c, h, w];
        let (p, t, m) = (uniform(&shape, 30), uniform(&shape, 31), holes(3, h, w, 0.3, 32));
        let v = (random(&[3, 2, h, w], 33) * 3.0).unwrap();
        let weights = LossWeights::default();
        let (whole, gp, gv) = evaluate(&p, &t, &m, &v, &weights);
        let counts = LossCounts::of(&m).unwrap();
        let (mut sum, mut grad_p, mut grad_v) = ([0f64; 4], Vec::new(), Vec::new());
        for (start, len) in [(0, 1), (1, 2)] {
            let part = |x: &Tensor| x.narrow(0, start, len).unwrap();
            let (pp, pv) = (Var::from_tensor(&part(&p)).unwrap(), Var::from_tensor(&part(&v)).unwrap());
            let terms = ivp_loss_normalised(&pp, &part(&t), &part(&m), Some(&pv), &weights, &counts).unwrap();
            for (s, term) in sum.iter_mut().zip([&terms.mse, &terms.ssim, &terms.smooth, &terms.total]) {
                *s += scalar(term) as f64;
            }
            let grads = terms.total.backward().unwrap();
            grad_p.extend(flat(grads.get(&pp).unwrap()));
            grad_v.extend(flat(grads.get(&pv).unwrap()));
        }
        for (s, term) in sum.iter().zip([&whole.mse, &whole.ssim, &whole.smooth, &whole.total]) {
            assert!((s - scalar(term) as f64).abs() <= 1e-6 * s.abs(), "{s} vs {term}");
        }
        for (parts, whole) in [(grad_p, flat(&gp)), (grad_v, flat(&gv))] {
            let largest = whole.iter().fold(0f32, |a, g| a.max(g.abs()));
            assert!(parts.iter().zip(&whole).all(|(a, b)| (a - b).abs() <= 1e-5 * largest));
        }
        // With its own counts, the whole batch's loss is exactly `ivp_loss`.
        let own = ivp_loss_normalised(&p, &t, &m, Some(&v), &weights, &counts).unwrap();
        assert_eq!(scalar(&own.total), scalar(&whole.total));
    }

    #[test]
    fn all_hole_mask_is_the_plain_mean() {
        let [b, _, h, w] = SHAPE;
        let (p, t) = (uniform(&SHAPE, 8), uniform(&SHAPE, 9));
        let v = random(&[b, 2, h, w], 10);
        let m = Tensor::ones((b, 1, h, w), DType::F32, &Device::Cpu).unwrap();
        let (terms, gp, gv) = evaluate(&p, &t, &m, &v, &LossWeights::default());
        let plain_mse = scalar(&(&p - &t).unwrap().sqr().unwrap().mean_all().unwrap());
        assert!((scalar(&terms.mse) - plain_mse).abs() < 1e-6 * plain_mse);
        // Two independent uniform images. Without the structure term, SSIM compares only local means
        // and spreads, which match: the loss is small (about 0.02), though not 0.
        let ssim = scalar(&terms.ssim);
        assert!(ssim > 0.01 && ssim < 0.05, "{ssim}");
        // A flattened prediction (a quarter of the spread) loses on contrast.
        let flatter = (&t * 0.25).unwrap().affine(1.0, 0.375).unwrap();
        let low = scalar(&masked_ssim_loss(&flatter, &t, &m).unwrap());
        assert!(low > 0.2, "{low}");
        assert!(scalar(&terms.smooth) > 0.0);
        assert!(all_finite(&gp) && all_finite(&gv));
    }

    #[test]
    fn equal_constant_images() {
        let [b, _, h, w] = SHAPE;
        let p = (Tensor::ones(&SHAPE[..], DType::F32, &Device::Cpu).unwrap() * 0.5).unwrap();
        let v = Tensor::zeros((b, 2, h, w), DType::F32, &Device::Cpu).unwrap();
        let m = holes(b, h, w, 0.5, 11);
        let (terms, gp, gv) = evaluate(&p, &p, &m, &v, &LossWeights::default());
        assert_eq!(scalar(&terms.mse), 0.0);
        assert_eq!(scalar(&terms.smooth), 0.0);
        // s is 1 up to the reference's 1e-12 under the root: 2e-6 / C2 ~ 0.0022 above 1 at most.
        let ssim = scalar(&terms.ssim);
        assert!((-2.3e-3..=0.0).contains(&ssim), "{ssim}");
        assert!(all_finite(&gp) && all_finite(&gv));
        // Equal (non-constant) images: likewise.
        let q = uniform(&SHAPE, 12);
        let ssim = scalar(&masked_ssim_loss(&q, &q, &m).unwrap());
        assert!((-2.3e-3..=0.0).contains(&ssim), "{ssim}");
    }

    #[test]
    fn huge_vectors_stay_finite() {
        let [b, _, h, w] = SHAPE;
        let (p, t) = (uniform(&SHAPE, 13), uniform(&SHAPE, 14));
        let v = (random(&[b, 2, h, w], 15) * 1e6).unwrap();
        let m = holes(b, h, w, 0.6, 16);
        let (terms, gp, gv) = evaluate(&p, &t, &m, &v, &LossWeights::default());
        let smooth = scalar(&terms.smooth);
        assert!(smooth.is_finite() && smooth > 1e4, "{smooth}");
        assert!(scalar(&terms.total).is_finite());
        assert!(all_finite(&gp) && all_finite(&gv));
        assert!(flat(&gv).iter().any(|g| *g != 0.0));
    }

    #[test]
    fn one_pixel_by_hand() {
        // One hole pixel at (image 1, y 4, x 5): MSE is the mean of its three squared errors, its
        // gradient 2 (p - t) / 3 there and 0 elsewhere; no pair of hole pixels, no smoothness.
        let [b, c, h, w] = SHAPE;
        let (p, t) = (uniform(&SHAPE, 17), uniform(&SHAPE, 18));
        let mut mv = vec![0f32; b * h * w];
        mv[(h + 4) * w + 5] = 1.0;
        let m = tensor(mv, &[b, 1, h, w]);
        let v = random(&[b, 2, h, w], 19);
        let (pv, tv) = (flat(&p), flat(&t));
        let at = |ch: usize| ((c + ch) * h + 4) * w + 5;
        let want: f64 = (0..c).map(|ch| (pv[at(ch)] as f64 - tv[at(ch)] as f64).powi(2)).sum::<f64>() / 3.0;
        let weights = LossWeights { mse: 1.0, ssim: 0.0, smooth: 1.0 };
        let (terms, gp, _) = evaluate(&p, &t, &m, &v, &weights);
        assert!((scalar(&terms.mse) as f64 - want).abs() < 1e-7, "{} vs {want}", scalar(&terms.mse));
        assert_eq!(scalar(&terms.smooth), 0.0);
        let gp = flat(&gp);
        for (i, g) in gp.iter().enumerate() {
            let want = match (0..c).find(|&ch| at(ch) == i) {
                Some(_) => 2.0 * (pv[i] - tv[i]) / 3.0,
                None => 0.0,
            };
            assert!((g - want).abs() < 1e-6, "[{i}]: {g} vs {want}");
        }
    }

    /// Away from the border (where the window's zero padding counts), two equal constant images
    /// have equal means and no variance: s = (2 mu^2 + C1)(2e-6 + C2) / ((2 mu^2 + C1) C2), so the
    /// loss is -2e-6 / C2 whatever the level, up to the f32 rounding of `blur(a^2) - mu^2`: a few
    /// ulps of level^2, over C2 in the denominator, which moves the loss by up to 3e-4 at level 0.9
    /// but under 3e-5 at the dark levels tested (where a wrong C1 would move it by 1e-3 to 1e-2).
    #[test]
    fn ssim_of_equal_constant_images_by_hand() {
        let (h, w) = (25, 25);
        let interior: Vec<f32> =
            (0..h * w).map(|i| f32::from((6..19).contains(&(i / w)) && (6..19).contains(&(i % w)))).collect();
        let m = tensor(interior, &[1, 1, h, w]);
        let expected = (-2.0 * SQRT_EPS.sqrt() / SSIM_C2) as f32;
        for level in [0.1f32, 0.15, 0.2, 0.25] {
            let p = tensor(vec![level; 3 * h * w], &[1, 3, h, w]);
            let loss = scalar(&masked_ssim_loss(&p, &p, &m).unwrap());
            assert!((loss - expected).abs() <= 1e-4, "level {level}: {loss} vs {expected}");
        }
    }

    /// A 2x2 image, all holes, truth constant (edge weights 1): x pairs |1 - 0| and |4 - 2| over
    /// 2 pairs, y pairs |2 - 0| and |4 - 1| over 2 pairs: 1.5 + 2.5 (the y component is 0).
    #[test]
    fn smoothness_of_a_two_by_two_image_by_hand() {
        let v = tensor(vec![0.0, 1.0, 2.0, 4.0, 0.0, 0.0, 0.0, 0.0], &[1, 2, 2, 2]);
        let t = tensor(vec![0.5; 12], &[1, 3, 2, 2]);
        let m = tensor(vec![1.0; 4], &[1, 1, 2, 2]);
        let loss = scalar(&smoothness_loss(&v, &t, &m).unwrap());
        assert!((loss - 4.0).abs() < 1e-6, "{loss}");
    }

    /// The total is the weighted sum of the three terms, each weight on its own term.
    #[test]
    fn the_total_weighs_each_term_by_its_weight() {
        let (p, t) = (uniform(&SHAPE, 21), uniform(&SHAPE, 22));
        let m = holes(SHAPE[0], SHAPE[2], SHAPE[3], 0.5, 23);
        let v = (random(&[SHAPE[0], 2, SHAPE[2], SHAPE[3]], 24) * 3.0).unwrap();
        let weights = LossWeights { mse: 0.7, ssim: 1.9, smooth: 0.3 };
        let terms = ivp_loss(&p, &t, &m, Some(&v), &weights).unwrap();
        let (mse, ssim, smooth) = (scalar(&terms.mse), scalar(&terms.ssim), scalar(&terms.smooth));
        assert!(mse > 0.0 && ssim > 0.0 && smooth > 0.0, "every term counts here: {mse} {ssim} {smooth}");
        let expected = 0.7 * mse + 1.9 * ssim + 0.3 * smooth;
        assert!((scalar(&terms.total) - expected).abs() <= 1e-6 * expected, "{} vs {expected}", scalar(&terms.total));
    }

    #[test]
    fn smoothness_of_one_pair_by_hand() {
        // Hole pixels (y 2, x 3) and (y 2, x 4) of a 1x3x5x6 image: one horizontal pair, no
        // vertical one. lx = exp(-10 mean_c |t(4) - t(3)|) (|dv_x| + |dv_y|) / 1.
        let (h, w) = (5, 6);
        let t = uniform(&[1, 3, h, w], 20);
        let v = (random(&[1, 2, h, w], 21) * 4.0).unwrap();
        let mut mv = vec![0f32; h * w];
        mv[2 * w + 3] = 1.0;
        mv[2 * w + 4] = 1.0;
        let m = tensor(mv, &[1, 1, h, w]);
        let (tv, vv) = (flat(&t), flat(&v));
        let px = |plane: usize, x: usize| (plane * h + 2) * w + x;
        let mean_dt = (0..3).map(|c| (tv[px(c, 4)] - tv[px(c, 3)]).abs() as f64).sum::<f64>() / 3.0;
        let dv = (0..2).map(|c| (vv[px(c, 4)] - vv[px(c, 3)]).abs() as f64).sum::<f64>();
        let want = (-10.0 * mean_dt).exp() * dv;
        let got = scalar(&smoothness_loss(&v, &t, &m).unwrap()) as f64;
        assert!((got - want).abs() < 1e-6 * want, "{got} vs {want}");
    }

    #[test]
    fn without_vectors_the_smoothness_term_is_zero() {
        let [b, _, h, w] = SHAPE;
        let (p, t, m) = (uniform(&SHAPE, 22), uniform(&SHAPE, 23), holes(b, h, w, 0.2, 24));
        let terms = ivp_loss(&p, &t, &m, None, &LossWeights::default()).unwrap();
        assert_eq!(scalar(&terms.smooth), 0.0);
        assert_eq!(scalar(&terms.total), scalar(&(&terms.mse + &terms.ssim).unwrap()));
    }

    #[test]
    fn tiny_and_odd_sizes() {
        for (h, w) in [(1, 1), (1, 4), (3, 1), (2, 2)] {
            let shape = [1, 3, h, w];
            let m = Tensor::ones((1, 1, h, w), DType::F32, &Device::Cpu).unwrap();
            let v = random(&[1, 2, h, w], 25);
            let (terms, gp, gv) = evaluate(&uniform(&shape, 26), &uniform(&shape, 27), &m, &v, &LossWeights::default());
            assert!(scalar(&terms.total).is_finite(), "{h}x{w}");
            assert!(all_finite(&gp) && all_finite(&gv), "{h}x{w}");
        }
    }

    #[test]
    fn rejects_mismatched_shapes() {
        let [b, _, h, w] = SHAPE;
        let (p, t) = (uniform(&SHAPE, 1), uniform(&SHAPE, 2));
        let m = holes(b, h, w, 0.5, 3);
        // Each input checked on its own, by the loss's own message (not a later op's).
        let message = |p: &Tensor, t: &Tensor, m: &Tensor| {
            ivp_loss(p, t, m, None, &LossWeights::default()).unwrap_err().to_string()
        };
        assert!(message(&p, &t.narrow(3, 0, w - 1).unwrap(), &m).starts_with("ivp_loss: prediction"));
        assert!(message(&p, &t, &m.narrow(2, 0, h - 1).unwrap()).starts_with("ivp_loss: prediction"));
        let f64_of = |x: &Tensor| x.to_dtype(DType::F64).unwrap();
        for (p, t, m) in
            [(f64_of(&p), t.clone(), m.clone()), (p.clone(), f64_of(&t), m.clone()), (p.clone(), t.clone(), f64_of(&m))]
        {
            assert!(message(&p, &t, &m).starts_with("ivp_loss: f32 tensors expected"));
        }
        let v = random(&[b, 3, h, w], 4);
        assert!(ivp_loss(&p, &t, &m, Some(&v), &LossWeights::default()).is_err());
    }

    /// Central differences of the total (an f32 computation) with step 1e-2, against the analytic
    /// gradient: `|fd - analytic| <= 1e-2 |analytic|` over each input's whole gradient. All weights
    /// 1, so that the vectors' gradient is not lost in the rounding of the other terms.
    #[test]
    fn gradient_matches_finite_differences() {
        let (b, c, h, w) = (2, 3, 6, 7);
        let (p, t) = (uniform(&[b, c, h, w], 30), uniform(&[b, c, h, w], 31));
        let v = (random(&[b, 2, h, w], 32) * 2.0).unwrap();
        let m = holes(b, h, w, 0.5, 33);
        let weights = LossWeights { mse: 1.0, ssim: 1.0, smooth: 1.0 };
        let (_, gp, gv) = evaluate(&p, &t, &m, &v, &weights);
        let total =
            |p: &Tensor, v: &Tensor| -> f64 { scalar(&ivp_loss(p, &t, &m, Some(v), &weights).unwrap().total) as f64 };
        let eps = 1e-2f32;
        let check = |x: &Tensor, analytic: &Tensor, loss: &dyn Fn(&Tensor) -> f64, name: &str| {
            let differences = central_differences(&flat(x), eps, |v| loss(&tensor(v, x.dims())));
            let analytic = flat(analytic);
            let err = analytic.iter().zip(&differences).map(|(&a, fd)| (fd - a as f64).powi(2)).sum::<f64>().sqrt();
            let norm = analytic.iter().map(|&a| (a as f64).powi(2)).sum::<f64>().sqrt();
            println!("{name}: relative error {:.2e} (gradient norm {norm:.3e})", err / norm);
            assert!(norm > 1e-3, "{name}: gradient norm {norm}");
            assert!(err <= 1e-2 * norm, "{name}: error {err} for a gradient of norm {norm}");
        };
        check(&p, &gp, &|p| total(p, &v), "prediction");
        check(&v, &gv, &|v| total(&p, v), "vectors");
    }

    // Parity with the PyTorch reference at the formulas' kinks (flat patches, equal neighbours)
    // is checked against a committed fixture: tests/tests/torch_parity.rs.
}
