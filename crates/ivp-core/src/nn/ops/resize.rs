//! Resizing of (B, C, H, W) maps as candle custom ops with correct backward passes (ALGORITHMS.md §6.1, §8).
//!
//! - [`upsample_nearest2x_to`]: nearest x2 upsampling cropped to the skip connection's size, as in
//!   the U-Net decoder. candle's own `upsample_nearest2d` backward overwrites instead of adding the
//!   gradients of the four copies of a pixel; here they are summed.
//! - [`upsample_bilinear_to`]: bilinear resizing with half-pixel centres (PyTorch's
//!   `align_corners=False`), as in the depth head; candle's `upsample_bilinear2d` has no backward.
//!
//! Determinism: forward passes are parallel over output rows (each written by one thread); the
//! nearest backward over input rows (each a fixed sum); the bilinear backward, a scatter-add, over
//! (image, channel) planes, each accumulated sequentially in pixel order. Results are bit-identical
//! for any number of rayon threads.

use crate::nn::ops::{contiguous_values, profile};
use candle_core::{bail, CpuStorage, CustomOp1, CustomOp2, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

/// Nearest x2 upsampling of `x` (B, C, H, W), cropped to (B, C, height, width): output pixel
/// (ox, oy) is input pixel (ox / 2, oy / 2). Needs `height <= 2 H` and `width <= 2 W`. Equals
/// PyTorch's `F.interpolate(x, size=(height, width), mode="nearest")` for height in {2H - 1, 2H} and
/// width in {2W - 1, 2W}. f32 on the CPU; the gradient adds up the copies of each input pixel.
pub fn upsample_nearest2x_to(x: &Tensor, height: usize, width: usize) -> Result<Tensor> {
    check(x, "upsample_nearest2x_to")?;
    let (_, _, h, w) = x.dims4()?;
    if height > 2 * h || width > 2 * w {
        bail!("upsample_nearest2x_to: {:?} to {height}x{width}, more than twice the size", x.dims());
    }
    profile::timed("upsample nearest", || x.contiguous()?.apply_op1(Nearest2x { height, width }))
}

/// Bilinear resizing of `x` (B, C, H, W) to (B, C, height, width) with half-pixel centres: output
/// pixel i of an axis reads input position `(i + 0.5) in / out - 0.5`, clamped at 0 below, between
/// the two neighbouring pixels (the last pixel repeats at the far edge). Equals PyTorch's
/// `F.interpolate(x, size=(height, width), mode="bilinear", align_corners=False)`. f32 on the CPU,
/// any sizes (up or down, though downsizing does not average like an area filter).
pub fn upsample_bilinear_to(x: &Tensor, height: usize, width: usize) -> Result<Tensor> {
    check(x, "upsample_bilinear_to")?;
    let (_, _, h, w) = x.dims4()?;
    if (h == 0 || w == 0) && height * width > 0 {
        bail!("upsample_bilinear_to: {:?} to {height}x{width}, empty input", x.dims());
    }
    profile::timed("upsample bilinear", || x.contiguous()?.apply_op1(Bilinear { height, width }))
}

fn check(x: &Tensor, name: &str) -> Result<()> {
    if x.dtype() != DType::F32 || !x.device().is_cpu() {
        bail!("{name}: an f32 tensor on the CPU expected, got {:?} on {:?}", x.dtype(), x.device());
    }
    Ok(())
}

/// The forward nearest op.
#[derive(Clone, Copy, Debug)]
struct Nearest2x {
    height: usize,
    width: usize,
}

impl CustomOp1 for Nearest2x {
    fn name(&self) -> &'static str {
        "ivp-upsample-nearest2x"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, c, h, w) = l.shape().dims4()?;
        let (height, width) = (self.height, self.width);
        let x = contiguous_values(s, l, "resize")?;
        let mut out = vec![0f32; batch * c * height * width];
        if width > 0 {
            // Output row r is row oy = r % height of plane r / height.
            out.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
                let (plane, oy) = (r / height, r % height);
                let src = &x[(plane * h + oy / 2) * w..][..w];
                row.iter_mut().enumerate().for_each(|(ox, o)| *o = src[ox / 2]);
            });
        }
        Ok((CpuStorage::F32(out), Shape::from((batch, c, height, width))))
    }

    fn bwd(&self, x: &Tensor, _res: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        let (_, _, h, w) = x.dims4()?;
        profile::timed("upsample nearest", || Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&Nearest2xGrad { h, w })?)))
    }
}

/// The gradient of [`Nearest2x`] on the output gradient (B, C, height, width): (B, C, H, W), each
/// input pixel the sum of the gradients of its (up to four) copies.
#[derive(Clone, Copy, Debug)]
struct Nearest2xGrad {
    h: usize,
    w: usize,
}

impl CustomOp1 for Nearest2xGrad {
    fn name(&self) -> &'static str {
        "ivp-upsample-nearest2x-grad"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, c, height, width) = l.shape().dims4()?;
        let (h, w) = (self.h, self.w);
        if height > 2 * h || width > 2 * w {
            bail!("upsample_nearest2x_to gradient: {:?} for a {h}x{w} input", l.dims());
        }
        let grad = contiguous_values(s, l, "resize")?;
        let mut dx = vec![0f32; batch * c * h * w];
        if w > 0 {
            // Input row r is row iy = r % h of plane r / h; it collects output rows 2 iy and 2 iy + 1.
            dx.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
                let (plane, iy) = (r / h, r % h);
                for oy in (2 * iy..2 * iy + 2).filter(|&oy| oy < height) {
                    let src = &grad[(plane * height + oy) * width..][..width];
                    for (ox, g) in src.iter().enumerate() {
                        row[ox / 2] += g;
                    }
                }
            });
        }
        Ok((CpuStorage::F32(dx), Shape::from((batch, c, h, w))))
    }
}

/// The decoder's step input in one op: `x` (B, Cx, h, w) upsampled nearest x2 and cropped to the
/// skip's size, then `skip` (B, Cs, H, W), concatenated along the channels: (B, Cx + Cs, H, W).
/// Equals `cat([upsample_nearest2x_to(x, H, W), skip], 1)` without the intermediate upsampled map
/// (at 1080p and width 1, 535 MB before the last layer) and its extra copy, forward and backward.
pub fn upsample_concat(x: &Tensor, skip: &Tensor) -> Result<Tensor> {
    check(x, "upsample_concat")?;
    check(skip, "upsample_concat")?;
    let (b, _, h, w) = x.dims4()?;
    let (bs, _, height, width) = skip.dims4()?;
    if b != bs || height > 2 * h || width > 2 * w {
        bail!("upsample_concat: {:?} cannot be upsampled x2 to the skip {:?}", x.dims(), skip.dims());
    }
    profile::timed("upsample nearest + concat", || x.contiguous()?.apply_op2(&skip.contiguous()?, UpConcat))
}

/// The forward op of [`upsample_concat`] on (x, skip).
#[derive(Clone, Copy, Debug)]
struct UpConcat;

impl CustomOp2 for UpConcat {
    fn name(&self) -> &'static str {
        "ivp-upsample-concat"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, cx, h, w) = l1.shape().dims4()?;
        let (_, cs, height, width) = l2.shape().dims4()?;
        let (x, skip) = (contiguous_values(s1, l1, "upsample_concat")?, contiguous_values(s2, l2, "upsample_concat")?);
        let ct = cx + cs;
        let mut out = vec![0f32; batch * ct * height * width];
        if width > 0 {
            // Output row r is row oy = r % height of output plane r / height = (image, channel).
            out.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
                let (plane, oy) = (r / height, r % height);
                let (b, c) = (plane / ct, plane % ct);
                if c < cx {
                    let src = &x[((b * cx + c) * h + oy / 2) * w..][..w];
                    row.iter_mut().enumerate().for_each(|(ox, o)| *o = src[ox / 2]);
                } else {
                    row.copy_from_slice(&skip[((b * cs + c - cx) * height + oy) * width..][..width]);
                }
            });
        }
        Ok((CpuStorage::F32(out), Shape::from((batch, ct, height, width))))
    }

    fn bwd(&self, x: &Tensor, skip: &Tensor, _res: &Tensor, grad: &Tensor) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let (_, cx, h, w) = x.dims4()?;
        let cs = skip.dim(1)?;
        profile::timed("upsample nearest + concat", || {
            let grad = grad.contiguous()?;
            let dx = match x.track_op() {
                true => Some(grad.apply_op1_no_bwd(&UpConcatGradX { cx, h, w })?),
                false => None,
            };
            let dskip = match skip.track_op() {
                true => Some(grad.narrow(1, cx, cs)?.contiguous()?),
                false => None,
            };
            Ok((dx, dskip))
        })
    }
}

/// The gradient of [`UpConcat`] for `x`, on the output gradient (B, Cx + Cs, H, W): (B, Cx, h, w),
/// each input pixel the sum of the gradients of its (up to four) copies.
#[derive(Clone, Copy, Debug)]
struct UpConcatGradX {
    cx: usize,
    h: usize,
    w: usize,
}

impl CustomOp1 for UpConcatGradX {
    fn name(&self) -> &'static str {
        "ivp-upsample-concat-grad"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, ct, height, width) = l.shape().dims4()?;
        let (cx, h, w) = (self.cx, self.h, self.w);
        let grad = contiguous_values(s, l, "upsample_concat")?;
        let mut dx = vec![0f32; batch * cx * h * w];
        if w > 0 {
            // Input row r is row iy = r % h of plane r / h = (image, channel); it collects output
            // rows 2 iy and 2 iy + 1 of the same channel, in that order.
            dx.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
                let (plane, iy) = (r / h, r % h);
                let (b, c) = (plane / cx, plane % cx);
                for oy in (2 * iy..2 * iy + 2).filter(|&oy| oy < height) {
                    let src = &grad[((b * ct + c) * height + oy) * width..][..width];
                    for (ox, g) in src.iter().enumerate() {
                        row[ox / 2] += g;
                    }
                }
            });
        }
        Ok((CpuStorage::F32(dx), Shape::from((batch, cx, h, w))))
    }
}

/// How output pixels of one axis read the input: (i0, i1, weight of i0, weight of i1), as in
/// PyTorch's `upsample_bilinear2d` with `align_corners=False`.
pub(crate) fn bilinear_taps(n_in: usize, n_out: usize) -> Vec<(usize, usize, f32, f32)> {
    let scale = n_in as f32 / n_out as f32;
    (0..n_out)
        .map(|i| {
            let src = (scale * (i as f32 + 0.5) - 0.5).max(0.0);
            let i0 = (src as usize).min(n_in - 1);
            let i1 = if i0 < n_in - 1 { i0 + 1 } else { i0 };
            let l1 = src - i0 as f32;
            (i0, i1, 1.0 - l1, l1)
        })
        .collect()
}

/// The forward bilinear op.
#[derive(Clone, Copy, Debug)]
struct Bilinear {
    height: usize,
    width: usize,
}

impl CustomOp1 for Bilinear {
    fn name(&self) -> &'static str {
        "ivp-upsample-bilinear"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, c, h, w) = l.shape().dims4()?;
        let (height, width) = (self.height, self.width);
        let x = contiguous_values(s, l, "resize")?;
        let mut out = vec![0f32; batch * c * height * width];
        if height * width > 0 {
            let (ty, tx) = (bilinear_taps(h, height), bilinear_taps(w, width));
            // Plane by plane: each input row interpolated along its columns once, then each output
            // row as a mix of two of those (upsampling by 2, four output rows read each input
            // row). The same operations as mixing along the columns for every output row.
            out.par_chunks_mut(height * width).zip(x.par_chunks(h * w)).for_each(|(out, plane)| {
                let mut along_columns = vec![0f32; h * width];
                for (row, input) in along_columns.chunks_exact_mut(width).zip(plane.chunks_exact(w)) {
                    for (o, &(x0, x1, lx0, lx1)) in row.iter_mut().zip(&tx) {
                        *o = lx0 * input[x0] + lx1 * input[x1];
                    }
                }
                for (row, &(y0, y1, ly0, ly1)) in out.chunks_exact_mut(width).zip(&ty) {
                    let (r0, r1) = (&along_columns[y0 * width..][..width], &along_columns[y1 * width..][..width]);
                    for ((o, &a), &b) in row.iter_mut().zip(r0).zip(r1) {
                        *o = ly0 * a + ly1 * b;
                    }
                }
            });
        }
        Ok((CpuStorage::F32(out), Shape::from((batch, c, height, width))))
    }

    fn bwd(&self, x: &Tensor, _res: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        let (_, _, h, w) = x.dims4()?;
        profile::timed("upsample bilinear", || Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&BilinearGrad { h, w })?)))
    }
}

/// The gradient of [`Bilinear`] on the output gradient (B, C, height, width): (B, C, H, W), the
/// scatter-add of each output gradient to its four input pixels.
#[derive(Clone, Copy, Debug)]
struct BilinearGrad {
    h: usize,
    w: usize,
}

impl CustomOp1 for BilinearGrad {
    fn name(&self) -> &'static str {
        "ivp-upsample-bilinear-grad"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, c, height, width) = l.shape().dims4()?;
        let (h, w) = (self.h, self.w);
        let grad = contiguous_values(s, l, "resize")?;
        let mut dx = vec![0f32; batch * c * h * w];
        if h * w > 0 && height * width > 0 {
            let (ty, tx) = (bilinear_taps(h, height), bilinear_taps(w, width));
            // Each plane is accumulated by one thread in pixel order: deterministic.
            dx.par_chunks_mut(h * w).enumerate().for_each(|(plane, dst)| {
                let gp = &grad[plane * height * width..][..height * width];
                for (oy, &(y0, y1, ly0, ly1)) in ty.iter().enumerate() {
                    for (ox, &(x0, x1, lx0, lx1)) in tx.iter().enumerate() {
                        let g = gp[oy * width + ox];
                        dst[y0 * w + x0] += ly0 * lx0 * g;
                        dst[y0 * w + x1] += ly0 * lx1 * g;
                        dst[y1 * w + x0] += ly1 * lx0 * g;
                        dst[y1 * w + x1] += ly1 * lx1 * g;
                    }
                }
            });
        }
        Ok((CpuStorage::F32(dx), Shape::from((batch, c, h, w))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::*;
    use candle_core::Var;

    #[test]
    fn upsample_concat_equals_upsample_then_cat_forward_and_backward() {
        for (i, (b, cx, cs, h, w)) in [(2, 3, 2, 5, 7), (1, 1, 1, 1, 1), (2, 2, 3, 4, 3)].into_iter().enumerate() {
            for (height, width) in [(2 * h, 2 * w), (2 * h - 1, 2 * w), (2 * h, 2 * w - 1), (2 * h - 1, 2 * w - 1)] {
                let seed = 10 * i as u64 + height as u64;
                let x = Var::from_tensor(&random(&[b, cx, h, w], seed)).unwrap();
                let skip = Var::from_tensor(&random(&[b, cs, height, width], seed + 1)).unwrap();
                let fused = upsample_concat(&x, &skip).unwrap();
                let reference =
                    Tensor::cat(&[&upsample_nearest2x_to(&x, height, width).unwrap(), skip.as_tensor()], 1).unwrap();
                assert_eq!(flat(&fused), flat(&reference), "{b}x{cx}+{cs}, {h}x{w} -> {height}x{width}");
                let r = random(fused.dims(), seed + 2);
                let grads = |y: &Tensor| {
                    let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                    (flat(g.get(&x).unwrap()), flat(g.get(&skip).unwrap()))
                };
                assert_eq!(grads(&fused), grads(&reference));
            }
        }
        let (x, skip) = (random(&[1, 2, 3, 3], 1), random(&[1, 2, 7, 6], 2));
        assert!(upsample_concat(&x, &skip).is_err(), "more than twice the size");
    }

    #[test]
    fn nearest_matches_candle_and_crops() {
        for (i, (b, c, h, w)) in [(2, 3, 5, 7), (1, 1, 1, 1), (1, 2, 4, 3)].into_iter().enumerate() {
            let x = random(&[b, c, h, w], i as u64);
            let full = x.upsample_nearest2d(2 * h, 2 * w).unwrap();
            for (height, width) in [(2 * h, 2 * w), (2 * h - 1, 2 * w), (2 * h, 2 * w - 1), (2 * h - 1, 2 * w - 1)] {
                let got = upsample_nearest2x_to(&x, height, width).unwrap();
                let want = full.narrow(2, 0, height).unwrap().narrow(3, 0, width).unwrap();
                assert_eq!(got.dims(), want.dims());
                assert_eq!(flat(&got), flat(&want), "{:?} to {height}x{width}", x.dims());
            }
        }
        let x = tensor(vec![1., 2., 3., 4.], &[1, 1, 2, 2]);
        let got = flat(&upsample_nearest2x_to(&x, 3, 3).unwrap());
        assert_eq!(got, vec![1., 1., 2., 1., 1., 2., 3., 3., 4.]);
        assert!(upsample_nearest2x_to(&x, 5, 4).is_err());
    }

    #[test]
    fn nearest_gradient_adds_the_copies() {
        let x = Var::from_tensor(&random(&[1, 1, 2, 3], 1)).unwrap();
        let g = upsample_nearest2x_to(&x, 3, 5).unwrap().sum_all().unwrap().backward().unwrap();
        // Rows: 2 copies, then 1 (cropped); columns: 2, 2, then 1 (cropped).
        assert_eq!(flat(g.get(&x).unwrap()), vec![4., 4., 2., 2., 2., 1.]);
    }

    #[test]
    fn bilinear_matches_candle_forward() {
        // candle's own resize has the same half-pixel convention, but no backward (ALGORITHMS.md §8).
        for (i, (b, c, h, w, height, width)) in
            [(2, 3, 5, 7, 10, 14), (1, 2, 4, 3, 7, 5), (1, 1, 1, 1, 2, 2), (1, 1, 9, 6, 17, 11)].into_iter().enumerate()
        {
            let x = random(&[b, c, h, w], 40 + i as u64);
            let got = flat(&upsample_bilinear_to(&x, height, width).unwrap());
            let want = flat(&x.upsample_bilinear2d(height, width, false).unwrap());
            assert_eq!(got.len(), want.len());
            for (j, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!((g - w).abs() <= 1e-4, "{:?} to {height}x{width}, value {j}: {g} vs {w}", x.dims());
            }
        }
    }

    #[test]
    fn bilinear_hand_computed() {
        // [0, 1] to 4: sources -0.25 (clamped to 0), 0.25, 0.75, 1.25 (last pixel repeated).
        let x = tensor(vec![0., 1., 2., 3.], &[1, 1, 2, 2]);
        let got = flat(&upsample_bilinear_to(&x, 4, 4).unwrap());
        let axis = [0.0, 0.25, 0.75, 1.0];
        let want: Vec<f32> = (0..16).map(|i| axis[i % 4] + 2.0 * axis[i / 4]).collect();
        assert_eq!(got, want);
        // Odd sizes, 3 to 5 columns: sources -0.2 (0), 0.4, 1.0, 1.6, 2.2 (the last pixel).
        let x = tensor(vec![0., 10., 20.], &[1, 1, 1, 3]);
        let got = flat(&upsample_bilinear_to(&x, 1, 5).unwrap());
        for (g, w) in got.iter().zip([0., 4., 10., 16., 20.]) {
            assert!((g - w).abs() < 1e-5, "{got:?}");
        }
        // The same size is a copy.
        let x = random(&[2, 3, 5, 7], 3);
        assert_eq!(flat(&upsample_bilinear_to(&x, 5, 7).unwrap()), flat(&x));
    }

    /// Checks the gradient of L = sum(f(x) r) against central differences (f is linear: exact up to
    /// rounding).
    fn check_gradient(f: impl Fn(&Tensor) -> Tensor, shape: &[usize], seed: u64) {
        let x = Var::from_tensor(&random(shape, seed)).unwrap();
        let y = f(&x);
        let r = random(y.dims(), seed + 1);
        let rv = flat(&r);
        let analytic = flat((&y * &r).unwrap().sum_all().unwrap().backward().unwrap().get(&x).unwrap());
        let loss = |v: Vec<f32>| -> f64 {
            flat(&f(&tensor(v, shape))).iter().zip(&rv).map(|(a, b)| *a as f64 * *b as f64).sum()
        };
        let differences = central_differences(&flat(&x), 0.5, loss);
        assert_matches_differences(&analytic, &differences, 1e-3, &format!("{shape:?}"));
    }

    #[test]
    fn gradients_match_finite_differences() {
        let shape = [2, 3, 5, 7];
        for (height, width) in [(10, 14), (9, 13), (10, 13), (9, 14)] {
            check_gradient(|x| upsample_nearest2x_to(x, height, width).unwrap(), &shape, 1);
        }
        for (height, width) in [(10, 14), (9, 13), (11, 8), (3, 4), (5, 7), (1, 1)] {
            check_gradient(|x| upsample_bilinear_to(x, height, width).unwrap(), &shape, 2);
        }
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let run = |threads: usize| -> Vec<Vec<u32>> {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let x = Var::from_tensor(&random(&[3, 4, 17, 13], 1)).unwrap();
                let a = upsample_nearest2x_to(&x, 33, 26).unwrap();
                let b = upsample_bilinear_to(&x, 31, 27).unwrap();
                let l = ((&a * random(a.dims(), 2)).unwrap().sum_all().unwrap()
                    + (&b * random(b.dims(), 3)).unwrap().sum_all().unwrap())
                .unwrap();
                let g = l.backward().unwrap();
                let bits = |t: &Tensor| flat(t).iter().map(|v| v.to_bits()).collect();
                vec![bits(&a), bits(&b), bits(g.get(&x).unwrap())]
            })
        };
        let one = run(1);
        for threads in [2, 3] {
            assert!(one == run(threads), "1 vs {threads} threads");
        }
    }

    #[test]
    fn nearest_gradient_matches_the_broadcast_reference() {
        // A reference made of candle ops whose backward is right: reshape, broadcast_as, reshape, crop.
        let (b, c, h, w) = (2, 3, 5, 4);
        let x = Var::from_tensor(&random(&[b, c, h, w], 7)).unwrap();
        let up = x.reshape((b, c, h, 1, w, 1)).unwrap().broadcast_as((b, c, h, 2, w, 2)).unwrap();
        let want = up.reshape((b, c, 2 * h, 2 * w)).unwrap().narrow(2, 0, 9).unwrap().narrow(3, 0, 7).unwrap();
        let r = random(want.dims(), 8);
        let gw = (&want * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let got = upsample_nearest2x_to(&x, 9, 7).unwrap();
        assert_eq!(flat(&got), flat(&want));
        let g = (&got * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let (a, e) = (flat(g.get(&x).unwrap()), flat(gw.get(&x).unwrap()));
        assert!(a.iter().zip(&e).all(|(a, e)| (a - e).abs() < 1e-5), "{a:?} vs {e:?}");
    }
}
