//! Bilinear sampling of an image at per-pixel offsets (ALGORITHMS.md §6.3) as a candle custom op, with a
//! hand-written backward for both the image and the offsets (candle has no `grid_sample`).
//!
//! Output pixel (x, y) of channel c is the bilinear read of the image at (x + a, y + b), where
//! (a, b) are the two channels of the vector field; corners outside the frame read 0. This is
//! PyTorch's `grid_sample(mode="bilinear", padding_mode="zeros", align_corners=True)` with the grid
//! built from pixel offsets. At integer positions the weights come from `floor`, as in PyTorch, so
//! the offset gradient there is the one-sided (right) derivative.
//!
//! Determinism: every output and gradient value is computed by the same sequence of operations
//! whatever the number of rayon threads. The forward pass is parallel over output rows and the
//! offset gradient over (image, row) pairs, each written by one thread (the channel sum in channel
//! order); the image gradient, a scatter-add, is parallel over (image, channel) planes, each plane
//! accumulated sequentially in pixel order.

use crate::nn::ops::{contiguous_values, profile};
use candle_core::{bail, CpuStorage, CustomOp2, CustomOp3, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

/// Samples `image` (B, C, H, W) at `(x + a, y + b)` for each pixel, with `vectors` (B, 2, H, W) in
/// pixels (channel 0: column offset a, channel 1: row offset b); bilinear, zeros outside the frame.
/// Output (B, C, H, W). All f32 on the CPU. Differentiable with respect to both arguments.
pub fn sample_bilinear(image: &Tensor, vectors: &Tensor) -> Result<Tensor> {
    for t in [image, vectors] {
        if t.dtype() != DType::F32 || !t.device().is_cpu() {
            bail!("sample_bilinear: f32 tensors on the CPU expected, got {:?} on {:?}", t.dtype(), t.device());
        }
    }
    let (b, _, h, w) = image.dims4()?;
    if vectors.dims() != [b, 2, h, w] {
        bail!("sample_bilinear: image {:?}, vectors {:?}", image.dims(), vectors.dims());
    }
    profile::timed("sampler", || image.contiguous()?.apply_op2(&vectors.contiguous()?, Sampler))
}

/// Farther than any frame is wide or high (and exact in f32).
const FAR: f32 = 16_777_216.0;

/// The four corners of a bilinear read at (sx, sy) in an h x w plane: the top-left corner
/// (x0, y0) = floor and the fractions (fx, fy) in [0, 1).
#[derive(Clone, Copy, Debug)]
struct Corners {
    x0: isize,
    y0: isize,
    fx: f32,
    fy: f32,
}

impl Corners {
    fn new(sx: f32, sy: f32) -> Self {
        // Reads far outside the frame (huge or non-finite vectors) read 0 wherever they are: move
        // them to a position that is outside every frame but whose corner indices cannot overflow.
        let tame = |s: f32| if s.is_finite() { s.clamp(-FAR, FAR) } else { -FAR };
        let (sx, sy) = (tame(sx), tame(sy));
        let (x0, y0) = (sx.floor(), sy.floor());
        Self { x0: x0 as isize, y0: y0 as isize, fx: sx - x0, fy: sy - y0 }
    }

    /// Reads the corners (top-left, top-right, bottom-left, bottom-right) of `plane`, 0 outside.
    fn read(&self, plane: &[f32], h: usize, w: usize) -> [f32; 4] {
        let at = |dx: isize, dy: isize| -> f32 {
            let (x, y) = (self.x0 + dx, self.y0 + dy);
            if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                plane[y as usize * w + x as usize]
            } else {
                0.0
            }
        };
        [at(0, 0), at(1, 0), at(0, 1), at(1, 1)]
    }

    /// Bilinear weights of the corners, in the order of [`Corners::read`].
    fn weights(&self) -> [f32; 4] {
        let (fx, fy) = (self.fx, self.fy);
        [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy]
    }

    /// Adds `g` times the corner weights to the corners of `plane` that are inside it.
    fn scatter(&self, plane: &mut [f32], h: usize, w: usize, g: f32) {
        for (i, wt) in self.weights().into_iter().enumerate() {
            let (x, y) = (self.x0 + (i & 1) as isize, self.y0 + (i >> 1) as isize);
            if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                plane[y as usize * w + x as usize] += g * wt;
            }
        }
    }
}

/// Shapes of one sampling.
#[derive(Clone, Copy, Debug)]
struct Geom {
    h: usize,
    w: usize,
}

impl Geom {
    /// The corners read by output pixel (x, y) of image `b`, from the vector field `v` (B, 2, H, W).
    fn corners(&self, v: &[f32], b: usize, y: usize, x: usize) -> Corners {
        let hw = self.h * self.w;
        let a = v[(2 * b) * hw + y * self.w + x];
        let bb = v[(2 * b + 1) * hw + y * self.w + x];
        Corners::new(x as f32 + a, y as f32 + bb)
    }
}

/// The forward op on (image, vectors).
#[derive(Clone, Copy, Debug)]
struct Sampler;

impl CustomOp2 for Sampler {
    fn name(&self) -> &'static str {
        "ivp-sample-bilinear"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, c, h, w) = l1.shape().dims4()?;
        if l2.dims() != [batch, 2, h, w] {
            bail!("sample_bilinear: image {:?}, vectors {:?}", l1.dims(), l2.dims());
        }
        let (img, v) = (contiguous_values(s1, l1, "sample_bilinear")?, contiguous_values(s2, l2, "sample_bilinear")?);
        let g = Geom { h, w };
        let mut out = vec![0f32; batch * c * h * w];
        if w > 0 {
            // One output row per work item: row r is (image, channel, y) = (r / (C H), r / H % C, r % H).
            out.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
                let (plane, y) = (r / h, r % h);
                let b = plane / c;
                let src = &img[plane * h * w..][..h * w];
                for (x, o) in row.iter_mut().enumerate() {
                    let k = g.corners(v, b, y, x);
                    let (p, wt) = (k.read(src, h, w), k.weights());
                    *o = p[0] * wt[0] + p[1] * wt[1] + p[2] * wt[2] + p[3] * wt[3];
                }
            });
        }
        Ok((CpuStorage::F32(out), Shape::from((batch, c, h, w))))
    }

    fn bwd(
        &self,
        image: &Tensor,
        vectors: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let grad = grad.contiguous()?;
        let di = match image.track_op() {
            true => Some(profile::timed("sampler", || vectors.apply_op2_no_bwd(&grad, &SamplerImageGrad))?),
            false => None,
        };
        let dv = match vectors.track_op() {
            true => Some(profile::timed("sampler", || image.apply_op3_no_bwd(vectors, &grad, &SamplerVectorGrad))?),
            false => None,
        };
        Ok((di, dv))
    }
}

/// Image gradient op on (vectors (B, 2, H, W), grad (B, C, H, W)): (B, C, H, W), the scatter-add of
/// the output gradient through the bilinear weights.
#[derive(Clone, Copy, Debug)]
struct SamplerImageGrad;

impl CustomOp2 for SamplerImageGrad {
    fn name(&self) -> &'static str {
        "ivp-sample-bilinear-image-grad"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, c, h, w) = l2.shape().dims4()?;
        if l1.dims() != [batch, 2, h, w] {
            bail!("sample_bilinear image gradient: vectors {:?}, grad {:?}", l1.dims(), l2.dims());
        }
        let (v, grad) = (contiguous_values(s1, l1, "sample_bilinear")?, contiguous_values(s2, l2, "sample_bilinear")?);
        let g = Geom { h, w };
        let mut di = vec![0f32; batch * c * h * w];
        if h * w > 0 {
            // Each plane is accumulated by one thread in pixel order: deterministic.
            di.par_chunks_mut(h * w).enumerate().for_each(|(plane, dst)| {
                let b = plane / c;
                let gp = &grad[plane * h * w..][..h * w];
                for y in 0..h {
                    for x in 0..w {
                        let gv = gp[y * w + x];
                        if gv != 0.0 {
                            g.corners(v, b, y, x).scatter(dst, h, w, gv);
                        }
                    }
                }
            });
        }
        Ok((CpuStorage::F32(di), Shape::from((batch, c, h, w))))
    }
}

/// Vector gradient op on (image, vectors, grad): (B, 2, H, W), the derivatives of the bilinear read
/// with respect to a and b times the output gradient, summed over the channels.
#[derive(Clone, Copy, Debug)]
struct SamplerVectorGrad;

impl CustomOp3 for SamplerVectorGrad {
    fn name(&self) -> &'static str {
        "ivp-sample-bilinear-vector-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (batch, c, h, w) = l1.shape().dims4()?;
        if l2.dims() != [batch, 2, h, w] || l3.dims() != l1.dims() {
            bail!("sample_bilinear vector gradient: {:?}, {:?}, {:?}", l1.dims(), l2.dims(), l3.dims());
        }
        let (img, v, grad) = (
            contiguous_values(s1, l1, "sample_bilinear")?,
            contiguous_values(s2, l2, "sample_bilinear")?,
            contiguous_values(s3, l3, "sample_bilinear")?,
        );
        let g = Geom { h, w };
        // Work item: one row (image b, row y) of both components, as [d/da (W values), d/db (W values)],
        // so that the corners are read once for both; then rearranged to (B, 2, H, W).
        let mut rows = vec![0f32; batch * h * 2 * w];
        if w > 0 {
            rows.par_chunks_mut(2 * w).enumerate().for_each(|(r, row)| {
                let (b, y) = (r / h, r % h);
                let (da, db) = row.split_at_mut(w);
                for x in 0..w {
                    let k = g.corners(v, b, y, x);
                    let (mut sa, mut sb) = (0f32, 0f32);
                    for ch in 0..c {
                        let plane = (b * c + ch) * h * w;
                        let gv = grad[plane + y * w + x];
                        let [p00, p10, p01, p11] = k.read(&img[plane..][..h * w], h, w);
                        // d/da: along x, blended over y; d/db: along y, blended over x.
                        sa += gv * ((1.0 - k.fy) * (p10 - p00) + k.fy * (p11 - p01));
                        sb += gv * ((1.0 - k.fx) * (p01 - p00) + k.fx * (p11 - p10));
                    }
                    (da[x], db[x]) = (sa, sb);
                }
            });
        }
        let mut dv = vec![0f32; batch * 2 * h * w];
        if w > 0 {
            for (r, row) in rows.chunks_exact(2 * w).enumerate() {
                let (b, y) = (r / h, r % h);
                for (comp, part) in row.chunks_exact(w).enumerate() {
                    dv[((2 * b + comp) * h + y) * w..][..w].copy_from_slice(part);
                }
            }
        }
        Ok((CpuStorage::F32(dv), Shape::from((batch, 2, h, w))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::{assert_matches_differences, central_differences, flat, tensor};
    use candle_core::Var;

    /// Deterministic values in [-1, 1) (candle cannot seed its CPU generator).
    fn random_vec(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
            })
            .collect()
    }

    /// A 1 x 1 x 3 x 4 image with values 0..12 (row-major) and a constant offset (a, b).
    fn case(a: f32, b: f32) -> Vec<f32> {
        let img = tensor((0..12).map(|v| v as f32).collect(), &[1, 1, 3, 4]);
        let mut v = vec![a; 12];
        v.extend(vec![b; 12]);
        flat(&sample_bilinear(&img, &tensor(v, &[1, 2, 3, 4])).unwrap())
    }

    #[test]
    fn integer_vectors_copy_pixels() {
        assert_eq!(case(0.0, 0.0), (0..12).map(|v| v as f32).collect::<Vec<_>>());
        // One column to the right: pixel (x, y) reads (x + 1, y); the last column is out of frame.
        assert_eq!(case(1.0, 0.0), vec![1., 2., 3., 0., 5., 6., 7., 0., 9., 10., 11., 0.]);
        // One row up: pixel (x, y) reads (x, y - 1).
        assert_eq!(case(0.0, -1.0), vec![0., 0., 0., 0., 0., 1., 2., 3., 4., 5., 6., 7.]);
        // Per-pixel vectors and several channels and images.
        let img = tensor((0..2 * 3 * 12).map(|v| v as f32).collect(), &[2, 3, 3, 4]);
        let mut v = vec![0f32; 2 * 2 * 12];
        v[5] = -1.0; // image 0, pixel (1, 1) reads (0, 1)
        v[12 + 5] = 1.0; // and row 2: (0, 2)
        v[24 + 12 + 2] = 2.0; // image 1, pixel (2, 0) reads (2, 2)
        let out = flat(&sample_bilinear(&img, &tensor(v, &[2, 2, 3, 4])).unwrap());
        for plane in 0..6 {
            let base = (plane * 12) as f32;
            let p = &out[plane * 12..][..12];
            if plane < 3 {
                assert_eq!(p[5], base + 8.0);
            } else {
                assert_eq!(p[2], base + 10.0);
            }
        }
    }

    #[test]
    fn half_pixels_average() {
        // Half a column: the mean of two neighbours; the last column averages with 0 outside.
        assert_eq!(case(0.5, 0.0), vec![0.5, 1.5, 2.5, 1.5, 4.5, 5.5, 6.5, 3.5, 8.5, 9.5, 10.5, 5.5]);
        // Half a pixel in both directions: the mean of a 2x2 block.
        let out = case(0.5, 0.5);
        assert_eq!(out[0], (0.0 + 1.0 + 4.0 + 5.0) / 4.0);
        assert_eq!(out[6], (6.0 + 7.0 + 10.0 + 11.0) / 4.0);
        // Partly outside: bottom-right corner, only one of four corners inside.
        assert_eq!(out[11], 11.0 / 4.0);
        // A quarter pixel: 3/4 and 1/4 weights.
        assert_eq!(case(0.25, 0.0)[1], 0.75 * 1.0 + 0.25 * 2.0);
    }

    #[test]
    fn out_of_frame_reads_zero() {
        for (a, b) in [(4.0, 0.0), (-4.0, 0.0), (0.0, 3.0), (0.0, -3.0), (100.5, -7.25), (-1.0, -1.0)] {
            let out = case(a, b);
            if (a, b) == (-1.0, -1.0) {
                // Only pixels with x >= 1 and y >= 1 read inside.
                assert_eq!(out, vec![0., 0., 0., 0., 0., 0., 1., 2., 0., 4., 5., 6.]);
            } else {
                assert_eq!(out, vec![0f32; 12], "({a}, {b})");
            }
        }
        // Past the left edge: column 0 reads -1.25 (both corners outside), column 1 reads -0.25
        // (only the right corner, column 0, inside, with weight 3/4).
        let out = case(-1.25, 0.0);
        assert_eq!((out[0], out[4], out[8]), (0.0, 0.0, 0.0));
        assert_eq!((out[1], out[5], out[9]), (0.0, 3.0, 6.0));
        // Partly outside the top-left corner.
        let out = case(-0.5, -0.5);
        assert_eq!(out[0], 0.0 / 4.0);
        assert_eq!(out[5], (0.0 + 1.0 + 4.0 + 5.0) / 4.0);
        assert_eq!(out[1], (0.0 + 1.0) / 4.0);
        assert_eq!(out[4], (0.0 + 4.0) / 4.0);
    }

    /// Random (image, vectors) of shape (b, c, h, w): vectors in about [-3, 3] with fractional parts
    /// in [0.2, 0.8], away from the integer kinks.
    fn random_case(b: usize, c: usize, h: usize, w: usize, seed: u64) -> (Var, Var) {
        let img = tensor(random_vec(b * c * h * w, seed), &[b, c, h, w]);
        let v: Vec<f32> = random_vec(b * 2 * h * w, seed + 1)
            .into_iter()
            .zip(random_vec(b * 2 * h * w, seed + 2))
            .map(|(i, f)| (i * 3.0).round() + 0.5 + 0.3 * f)
            .collect();
        (Var::from_tensor(&img).unwrap(), Var::from_tensor(&tensor(v, &[b, 2, h, w])).unwrap())
    }

    #[test]
    fn gradients_match_finite_differences() {
        for (i, (b, c, h, w)) in [(2, 3, 7, 5), (1, 1, 5, 9), (2, 2, 3, 3)].into_iter().enumerate() {
            let (img, vec) = random_case(b, c, h, w, 10 * i as u64);
            let r = tensor(random_vec(b * c * h * w, 99 + i as u64), &[b, c, h, w]);
            let rv = flat(&r);
            let y = sample_bilinear(&img, &vec).unwrap();
            let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let loss = |img: &Tensor, vec: &Tensor| -> f64 {
                let y = flat(&sample_bilinear(img, vec).unwrap());
                y.iter().zip(&rv).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            // Linear in the image (exact differences); smooth in the vectors between integers.
            for (arg, eps) in [(0, 0.5f32), (1, 1e-2)] {
                let args = [img.as_tensor().clone(), vec.as_tensor().clone()];
                let analytic = flat(g.get(&args[arg]).unwrap());
                let differences = central_differences(&flat(&args[arg]), eps, |v| {
                    let mut a = args.clone();
                    a[arg] = tensor(v, args[arg].dims());
                    loss(&a[0], &a[1])
                });
                assert_matches_differences(&analytic, &differences, 2e-3, &format!("case {i} arg {arg}"));
            }
        }
    }

    #[test]
    fn gradient_of_a_constant_image_is_skipped() {
        let (img, vec) = random_case(1, 2, 5, 4, 3);
        let img = img.as_tensor().detach();
        let g = sample_bilinear(&img, &vec).unwrap().sum_all().unwrap().backward().unwrap();
        assert!(g.get(&img).is_none());
        assert!(g.get(&vec).is_some());
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let run = |threads: usize| -> Vec<Vec<u32>> {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let (img, vec) = random_case(3, 3, 31, 29, 7);
                let y = sample_bilinear(&img, &vec).unwrap();
                let r = tensor(random_vec(y.elem_count(), 8), y.dims());
                let g = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let bits = |t: &Tensor| flat(t).iter().map(|v| v.to_bits()).collect();
                vec![bits(&y), bits(g.get(&img).unwrap()), bits(g.get(&vec).unwrap())]
            })
        };
        let one = run(1);
        for threads in [2, 3] {
            assert!(one == run(threads), "1 vs {threads} threads");
        }
    }

    #[test]
    fn rejects_each_input_of_another_dtype_by_name() {
        let img = tensor((0..12).map(|v| v as f32).collect(), &[1, 1, 3, 4]);
        let vec = tensor(vec![0.0; 24], &[1, 2, 3, 4]);
        let f64 = |t: &Tensor| t.to_dtype(DType::F64).unwrap();
        for (image, vectors) in [(f64(&img), vec.clone()), (img.clone(), f64(&vec))] {
            let err = sample_bilinear(&image, &vectors).unwrap_err().to_string();
            assert!(err.contains("sample_bilinear: f32 tensors on the CPU expected, got F64"), "{err}");
        }
    }

    #[test]
    fn a_frame_without_columns_gives_an_empty_output_and_empty_gradients() {
        let img = Var::from_tensor(&tensor(vec![], &[1, 1, 3, 0])).unwrap();
        let vec = Var::from_tensor(&tensor(vec![], &[1, 2, 3, 0])).unwrap();
        let out = sample_bilinear(&img, &vec).unwrap();
        assert_eq!(out.dims(), [1, 1, 3, 0]);
        let g = out.sum_all().unwrap().backward().unwrap();
        assert_eq!(g.get(&img).unwrap().dims(), [1, 1, 3, 0]);
        assert_eq!(g.get(&vec).unwrap().dims(), [1, 2, 3, 0]);
    }

    #[test]
    fn the_gradient_ops_refuse_inputs_of_other_shapes() {
        let (img, vec) = random_case(1, 2, 3, 4, 5);
        let grad = tensor(vec![1.0; 24], &[1, 2, 3, 4]);
        let small = tensor(vec![1.0; 12], &[1, 1, 3, 4]);
        assert!(img.apply_op3(&vec, &grad, SamplerVectorGrad).is_ok());
        let err = img.apply_op3(&vec, &small, SamplerVectorGrad).unwrap_err().to_string();
        assert!(err.contains("sample_bilinear vector gradient"), "{err}");
        let err = img.apply_op3(&small, &grad, SamplerVectorGrad).unwrap_err().to_string();
        assert!(err.contains("sample_bilinear vector gradient"), "{err}");
        assert!(vec.apply_op2(&grad, SamplerImageGrad).is_ok());
        let err = small.apply_op2(&grad, SamplerImageGrad).unwrap_err().to_string();
        assert!(err.contains("sample_bilinear image gradient"), "{err}");
    }

    #[test]
    fn strided_inputs_are_accepted() {
        let (img, vec) = random_case(1, 2, 5, 7, 4);
        let (img_t, vec_t) = (img.transpose(2, 3).unwrap(), vec.transpose(2, 3).unwrap()); // (.., 7, 5)
        let want = sample_bilinear(&img_t.contiguous().unwrap(), &vec_t.contiguous().unwrap()).unwrap();
        assert_eq!(flat(&sample_bilinear(&img_t, &vec_t).unwrap()), flat(&want));
        assert!(sample_bilinear(&img, &vec_t).is_err());
    }

    #[test]
    fn huge_and_non_finite_vectors_read_zero_with_zero_gradients() {
        for a in [1e6, -1e6, 1e30, -1e30, f32::MAX, f32::MIN, f32::INFINITY, f32::NEG_INFINITY, f32::NAN] {
            assert_eq!(case(a, 0.0), vec![0.0; 12], "a = {a}");
            assert_eq!(case(0.0, a), vec![0.0; 12], "b = {a}");
            let img = Var::from_tensor(&tensor((0..12).map(|v| v as f32).collect(), &[1, 1, 3, 4])).unwrap();
            let vec = Var::from_tensor(&tensor(vec![a; 24], &[1, 2, 3, 4])).unwrap();
            let g = sample_bilinear(&img, &vec).unwrap().sum_all().unwrap().backward().unwrap();
            assert!(flat(g.get(&img).unwrap()).iter().all(|v| *v == 0.0));
            assert!(flat(g.get(&vec).unwrap()).iter().all(|v| *v == 0.0));
        }
    }
}
