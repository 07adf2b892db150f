//! Separable Gaussian filtering for the SSIM loss (ALGORITHMS.md §6.4), with backward.
//!
//! [`gaussian_blur`] filters every channel of a (N, C, H, W) map on its own with the 11 x 11
//! Gaussian window of sigma 1.5 (normalised to sum 1) and zero padding, keeping the size: PyTorch's
//! `F.conv2d(t, gauss_window(c), padding=5, groups=c)` of the reference. The window is the outer
//! product of a 1-D kernel with itself, and zero padding keeps that product structure at the border
//! (a row outside the frame contributes a zero row), so the 2-D filter is exactly a row pass then a
//! column pass of 11 taps each: 22 multiply-adds per pixel instead of 121, and no im2col (candle's
//! grouped conv2d runs one im2col + matmul per channel, ALGORITHMS.md §8).
//!
//! Both passes add one whole tap at a time to a row (`out[x] += g[k] * src[x + k - 5]` over the
//! valid range of x), a loop the compiler vectorises; border pixels just skip the taps that fall
//! outside the frame, which is what zero padding means, so no padded copy is made.
//!
//! Determinism: each pass is parallel over output rows, each written by one thread, and every
//! output value is the sum of its taps in tap order: bit-identical for any number of threads.

use crate::metrics::{SSIM_RADIUS, SSIM_SIGMA};
use crate::nn::ops::{contiguous_values, profile};
use candle_core::{bail, CpuStorage, CustomOp1, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

/// Number of taps of the 1-D kernel.
const TAPS: usize = 2 * SSIM_RADIUS + 1;

/// Rows per rayon work item: one row is only ~11 W multiply-adds, too little to hand to a thread
/// alone.
const MIN_ROWS_PER_TASK: usize = 16;

/// Filters each channel of `x` (N, C, H, W) with the 11 x 11 Gaussian window of sigma 1.5, zero
/// padding, same output size; any H, W (also smaller than the window). f32 on the CPU.
/// Differentiable: the filter is its own adjoint (see `GaussianBlur::bwd`).
pub fn gaussian_blur(x: &Tensor) -> Result<Tensor> {
    if x.dtype() != DType::F32 || !x.device().is_cpu() {
        bail!("gaussian_blur: an f32 tensor on the CPU expected, got {:?} on {:?}", x.dtype(), x.device());
    }
    x.dims4()?;
    profile::timed("gaussian blur", || x.contiguous()?.apply_op1(GaussianBlur))
}

/// The normalised 1-D kernel `exp(-(k - 5)^2 / (2 sigma^2)) / sum`, k = 0..11, computed in f64 and
/// rounded once (the reference computes it in f32: the two differ by an ulp at most). Symmetric:
/// `g[k] == g[10 - k]` exactly, since (k - 5)^2 is.
fn kernel() -> [f32; TAPS] {
    let r = SSIM_RADIUS as f64;
    let raw: [f64; TAPS] = std::array::from_fn(|k| (-(k as f64 - r).powi(2) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp());
    let sum: f64 = raw.iter().sum();
    raw.map(|v| (v / sum) as f32)
}

/// The taps of output index `i` of an axis of length `n` that fall inside the frame: the tap range
/// and the matching first source index. Tap k reads source `i + k - 5`.
fn valid_taps(i: usize, n: usize) -> std::ops::Range<usize> {
    let lo = SSIM_RADIUS.saturating_sub(i);
    let hi = TAPS.min(n + SSIM_RADIUS - i);
    lo..hi.max(lo)
}

/// Row pass of one row: `out[x] = sum_k g[k] src[x + k - 5]`, zero outside. Tap by tap over the
/// valid output range of each tap, so that the inner loop is a vectorisable axpy.
fn blur_row(g: &[f32; TAPS], src: &[f32], out: &mut [f32]) {
    let w = src.len();
    out.fill(0.0);
    for (k, &gk) in g.iter().enumerate() {
        // Tap k is inside the frame for x + k - 5 in [0, w): x in [5 - k, w + 5 - k) within [0, w).
        let x0 = SSIM_RADIUS.saturating_sub(k);
        let x1 = w.min((w + SSIM_RADIUS).saturating_sub(k));
        if x0 >= x1 {
            continue;
        }
        let s0 = x0 + k - SSIM_RADIUS;
        for (o, s) in out[x0..x1].iter_mut().zip(&src[s0..s0 + (x1 - x0)]) {
            *o += gk * s;
        }
    }
}

/// The 2-D filter of contiguous (N, C, H, W) values.
fn blur(x: &[f32], planes: usize, h: usize, w: usize) -> Vec<f32> {
    let g = kernel();
    let mut out = vec![0f32; planes * h * w];
    if out.is_empty() {
        return out;
    }
    // Row pass into a temporary of the same size.
    let mut tmp = vec![0f32; planes * h * w];
    tmp.par_chunks_mut(w)
        .zip(x.par_chunks(w))
        .with_min_len(MIN_ROWS_PER_TASK)
        .for_each(|(dst, src)| blur_row(&g, src, dst));
    // Column pass: output row y of a plane adds the rows y - 5 ..= y + 5 of the temporary that exist.
    out.par_chunks_mut(w).enumerate().with_min_len(MIN_ROWS_PER_TASK).for_each(|(r, dst)| {
        let (plane, y) = (r / h, r % h);
        let src = &tmp[plane * h * w..][..h * w];
        for k in valid_taps(y, h) {
            let gk = g[k];
            let row = &src[(y + k - SSIM_RADIUS) * w..][..w];
            for (o, s) in dst.iter_mut().zip(row) {
                *o += gk * s;
            }
        }
    });
    out
}

/// The op. Its own gradient: see [`GaussianBlur::bwd`].
#[derive(Clone, Copy, Debug)]
struct GaussianBlur;

impl CustomOp1 for GaussianBlur {
    fn name(&self) -> &'static str {
        "ivp-gaussian-blur"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (n, c, h, w) = l.shape().dims4()?;
        let x = contiguous_values(s, l, "gaussian_blur")?;
        Ok((CpuStorage::F32(blur(x, n * c, h, w)), Shape::from((n, c, h, w))))
    }

    /// The filter is linear, y = A x, so the gradient is A^T dy. A is a correlation with the
    /// window over a zero-padded frame; its transpose is the correlation with the flipped window over
    /// the same zero-padded frame (the padding equals the radius on each side, so the sizes match),
    /// and the Gaussian window is symmetric: A^T = A. The backward is the same blur of the gradient
    /// (itself differentiable, for what it is worth).
    fn bwd(&self, _x: &Tensor, _res: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        profile::timed("gaussian blur", || Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&GaussianBlur)?)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::*;
    use candle_core::{Device, Var};

    /// The 2-D window of the reference's `gauss_window(c)`: (C, 1, 11, 11).
    fn window(c: usize) -> Tensor {
        let g = kernel();
        let w2: Vec<f32> = (0..c * TAPS * TAPS).map(|i| g[i / TAPS % TAPS] * g[i % TAPS]).collect();
        Tensor::from_vec(w2, (c, 1, TAPS, TAPS), &Device::Cpu).unwrap()
    }

    #[test]
    fn kernel_is_normalised_and_symmetric() {
        let g = kernel();
        assert!((g.iter().map(|&v| v as f64).sum::<f64>() - 1.0).abs() < 1e-6);
        for k in 0..TAPS {
            assert_eq!(g[k], g[TAPS - 1 - k]);
        }
        // Row 5 of the reference's `gauss_window(1)`, printed by PyTorch 2.15.
        let row5 = [0.000_273_561_22, 0.002_021_358_8, 0.009_576_627, 0.029_091_224, 0.056_661_967, 0.070_762_23];
        for (k, want) in row5.into_iter().enumerate() {
            assert!((g[5] * g[k] - want).abs() < 1e-8, "{k}: {} vs {want}", g[5] * g[k]);
        }
    }

    #[test]
    fn matches_candle_grouped_conv2d() {
        let shapes =
            [[2, 3, 7, 13], [1, 1, 3, 2], [1, 2, 17, 16], [1, 1, 1, 1], [2, 1, 12, 1], [1, 3, 11, 11], [1, 2, 30, 4]];
        for (i, shape) in shapes.into_iter().enumerate() {
            let x = random(&shape, i as u64 + 1);
            let got = gaussian_blur(&x).unwrap();
            let want = x.conv2d(&window(shape[1]), SSIM_RADIUS, 1, 1, shape[1]).unwrap();
            assert_eq!(got.dims(), want.dims());
            let (a, e) = (flat(&got), flat(&want));
            let err = a.iter().zip(&e).map(|(a, e)| (a - e).abs()).fold(0f32, f32::max);
            assert!(err < 1e-4, "{shape:?}: max error {err}");
        }
    }

    #[test]
    fn non_contiguous_input() {
        let x = random(&[2, 5, 9, 3], 4).transpose(2, 3).unwrap();
        assert!(!x.is_contiguous());
        let want = gaussian_blur(&x.contiguous().unwrap()).unwrap();
        assert_eq!(flat(&gaussian_blur(&x).unwrap()), flat(&want));
    }

    #[test]
    fn constant_image_stays_constant_away_from_the_border() {
        let (h, w) = (25, 31);
        let x = (Tensor::ones((1, 2, h, w), DType::F32, &Device::Cpu).unwrap() * 0.7).unwrap();
        let y = flat(&gaussian_blur(&x).unwrap());
        let r = SSIM_RADIUS;
        for (i, v) in y.iter().enumerate() {
            let (yy, xx) = (i / w % h, i % w);
            if (r..h - r).contains(&yy) && (r..w - r).contains(&xx) {
                assert!((v - 0.7).abs() < 1e-6, "({yy}, {xx}): {v}");
            } else {
                // Zero padding: the border loses the weight of the taps outside the frame.
                assert!(*v < 0.7 && *v > 0.7 * 0.25, "({yy}, {xx}): {v}");
            }
        }
    }

    #[test]
    fn gradient_is_the_blurred_gradient_and_matches_finite_differences() {
        for (seed, shape) in [[1, 2, 7, 9], [2, 1, 3, 2], [1, 1, 13, 12]].into_iter().enumerate() {
            let seed = seed as u64 * 10;
            let x = Var::from_tensor(&random(&shape, seed)).unwrap();
            let r = random(&shape, seed + 1);
            let y = gaussian_blur(&x).unwrap();
            let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let analytic = flat(grads.get(&x).unwrap());
            // Self-adjoint: d/dx sum(blur(x) r) = blur(r).
            let br = flat(&gaussian_blur(&r).unwrap());
            assert!(analytic.iter().zip(&br).all(|(a, b)| (a - b).abs() < 1e-6));
            // The loss is linear in x: central differences are exact up to rounding (f64 sums).
            let rv = flat(&r);
            let loss = |v: Vec<f32>| -> f64 {
                let y = flat(&gaussian_blur(&tensor(v, &shape)).unwrap());
                y.iter().zip(&rv).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            let differences = central_differences(&flat(&x), 0.5, loss);
            assert_matches_differences(&analytic, &differences, 1e-4, &format!("{shape:?}"));
        }
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let run = |threads: usize| -> Vec<Vec<u32>> {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let x = Var::from_tensor(&random(&[3, 4, 37, 29], 1)).unwrap();
                let y = gaussian_blur(&x).unwrap();
                let g = (&y * random(y.dims(), 2)).unwrap().sum_all().unwrap().backward().unwrap();
                let bits = |t: &Tensor| flat(t).iter().map(|v| v.to_bits()).collect();
                vec![bits(&y), bits(g.get(&x).unwrap())]
            })
        };
        let one = run(1);
        for threads in [2, 3] {
            assert!(one == run(threads), "1 vs {threads} threads");
        }
    }

    #[test]
    fn rejects_other_dtypes_and_ranks() {
        let x = random(&[1, 1, 4, 4], 1);
        assert!(gaussian_blur(&x.to_dtype(DType::F64).unwrap()).is_err());
        assert!(gaussian_blur(&x.reshape((1, 4, 4)).unwrap()).is_err());
    }
}
