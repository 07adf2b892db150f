//! Direct kernels for stride-1 convolutions with one or two output channels: the last layer of the
//! U-Net (2 outputs, the vectors) and of the depth head (1 output); and, forward only, four
//! outputs of a 5x5 kernel: the phases of the depth head's last layer at inference
//! (`conv2d_of_upsampled`).
//!
//! Through im2col these are matrix-vector products: every value of the k x k times larger im2col
//! matrix is written once and used for only one or two multiply-adds, so they ran at 5-15 GFLOP/s
//! and the depth head's last layer alone took a sixth of the convolution time of the default
//! recipe's training step. Here the input is copied once into zero-padded rows, and each block of
//! output pixels is summed in registers over all the taps, reading the padded rows at shifted
//! offsets: no im2col at all.
//!
//! Every value is computed by the same sequence of operations whatever the thread count: the
//! forward pass sums over input channels, kernel rows and kernel columns in that order; the weight
//! gradient sums over images and rows in order, in 8 lanes added up last. As the gemm calls of the
//! other layers, they run with subnormal floats flushed to zero.

use rayon::prelude::*;

use super::geom::{flushing_denormals, Geom, SharedMut};
use lanes::{Lanes, LANES};

/// Output rows per work item of the forward pass: the input rows it reads are padded once for
/// all of them (k - 1 rows more than the band).
const BAND_ROWS: usize = 16;

/// Registers of sums per output channel in the forward pass, for 1 and 2 outputs: 8 registers of
/// independent sums in both cases, enough to hide the latency of the multiply-adds.
const BLOCKS_1: usize = 8;
const BLOCKS_2: usize = 4;
const BLOCKS_4: usize = 2;

/// True when [`forward`] and [`weight_grad`] apply to this shape.
pub(super) fn applies(g: &Geom) -> bool {
    g.stride == 1 && (1..=2).contains(&g.cout) && matches!(g.k, 3 | 5 | 7)
}

/// True when [`forward`] applies to this shape.
pub(super) fn applies_forward(g: &Geom) -> bool {
    applies(g) || (g.stride == 1 && g.cout == 4 && g.k == 5)
}

/// The output row length rounded up to whole blocks of the forward pass (`BLOCKS_1 LANES` pixels
/// for one output, `BLOCKS_2 LANES` for two); the padded input rows are `k - 1` longer.
fn padded_width(g: &Geom) -> usize {
    g.wo.next_multiple_of(BLOCKS_1 * LANES)
}

/// Writes rows `iy0..iy0 + rows` of every channel of `image` (Cin, H, W), zero-padded: `pad`
/// zeros before each row and zeros after it up to `row_len`, and rows outside the image all zero.
/// `dst` is (Cin, rows, row_len).
fn pad_rows(g: &Geom, image: &[f32], iy0: isize, rows: usize, row_len: usize, dst: &mut [f32]) {
    for (ci, plane) in dst.chunks_exact_mut(rows * row_len).enumerate() {
        for (r, row) in plane.chunks_exact_mut(row_len).enumerate() {
            let iy = iy0 + r as isize;
            if iy < 0 || iy >= g.h as isize {
                row.fill(0.0);
                continue;
            }
            row[..g.pad].fill(0.0);
            row[g.pad..g.pad + g.w].copy_from_slice(&image[(ci * g.h + iy as usize) * g.w..][..g.w]);
            row[g.pad + g.w..].fill(0.0);
        }
    }
}

/// Forward pass, `out[b, co, oy, ox] = bias[co] + sum w[co, ci, kh, kw] x[b, ci, oy + kh - pad, ox + kw - pad]`,
/// one band of output rows of one image per work item.
pub(super) fn forward(g: &Geom, x: &[f32], w: &[f32], bias: Option<&[f32]>) -> Vec<f32> {
    match (g.cout, g.k) {
        (1, 3) => forward_n::<1, 3, BLOCKS_1>(g, x, w, bias),
        (1, 5) => forward_n::<1, 5, BLOCKS_1>(g, x, w, bias),
        (1, 7) => forward_n::<1, 7, BLOCKS_1>(g, x, w, bias),
        (2, 3) => forward_n::<2, 3, BLOCKS_2>(g, x, w, bias),
        (2, 5) => forward_n::<2, 5, BLOCKS_2>(g, x, w, bias),
        (2, 7) => forward_n::<2, 7, BLOCKS_2>(g, x, w, bias),
        (4, 5) => forward_n::<4, 5, BLOCKS_4>(g, x, w, bias),
        shape => unreachable!("no narrow kernel for (outputs, kernel) {shape:?}"),
    }
}

/// [`forward`] for `C` outputs and kernel `K`, in blocks of `N LANES` output pixels whose `C N`
/// registers of sums stay in registers over all the taps.
fn forward_n<const C: usize, const K: usize, const N: usize>(
    g: &Geom,
    x: &[f32],
    w: &[f32],
    bias: Option<&[f32]>,
) -> Vec<f32> {
    let block = N * LANES;
    let wo_pad = padded_width(g);
    debug_assert_eq!(wo_pad % block, 0);
    let row_len = wo_pad + K - 1;
    let band_in = BAND_ROWS + K - 1;
    let bands = g.ho.div_ceil(BAND_ROWS);
    let plane = g.ho * g.wo;
    // The taps as [ci][kh][kw][co]: read in that order below.
    let mut taps = vec![0f32; g.cin * K * K * C];
    for (i, t) in taps.iter_mut().enumerate() {
        *t = w[(i % C) * g.cin * K * K + i / C];
    }
    let bias: [f32; C] = std::array::from_fn(|co| bias.map_or(0.0, |b| b[co]));
    let mut out = vec![0f32; g.batch * C * plane];
    let out_ptr = SharedMut(out.as_mut_ptr());
    (0..g.batch * bands).into_par_iter().for_each_init(
        || vec![0f32; g.cin * band_in * row_len],
        |rows, item| {
            flushing_denormals(|| {
                let (b, band) = (item / bands, item % bands);
                let oy0 = band * BAND_ROWS;
                pad_rows(g, g.image(x, b), oy0 as isize - g.pad as isize, band_in, row_len, rows);
                let mut sums = [[[0f32; LANES]; N]; C];
                for r in 0..BAND_ROWS.min(g.ho - oy0) {
                    let oy = oy0 + r;
                    for x0 in (0..wo_pad).step_by(block) {
                        let mut acc: [[Lanes; N]; C] = bias.map(|v| [Lanes::splat(v); N]);
                        for ci in 0..g.cin {
                            for kh in 0..K {
                                let row = &rows[(ci * band_in + r + kh) * row_len + x0..][..block + K - 1];
                                let t = &taps[(ci * K + kh) * K * C..][..K * C];
                                for kw in 0..K {
                                    let tap: [Lanes; C] = std::array::from_fn(|co| Lanes::splat(t[kw * C + co]));
                                    for j in 0..N {
                                        let input = Lanes::load(&row[kw + j * LANES..]);
                                        for co in 0..C {
                                            acc[co][j] = input.mul_add(tap[co], acc[co][j]);
                                        }
                                    }
                                }
                            }
                        }
                        let len = block.min(g.wo.saturating_sub(x0));
                        for co in 0..C {
                            for j in 0..N {
                                acc[co][j].store(&mut sums[co][j]);
                            }
                            // SAFETY: pixels x0.. of row oy of channel co of image b, written by this item alone.
                            let dst = unsafe {
                                std::slice::from_raw_parts_mut(out_ptr.at((b * C + co) * plane + oy * g.wo + x0), len)
                            };
                            dst.copy_from_slice(&sums[co].as_flattened()[..len]);
                        }
                    }
                }
            })
        },
    );
    out
}

/// Weight gradient `dw[co, ci, kh, kw] = sum over b, oy, ox of grad[b, co, oy, ox] x[b, ci, oy + kh - pad, ox + kw - pad]`,
/// one input channel per work item. Returns (Cout, Cin k k) row-major.
pub(super) fn weight_grad(g: &Geom, x: &[f32], grad: &[f32]) -> Vec<f32> {
    match (g.cout, g.k) {
        (1, 3) => weight_grad_n::<1, 3>(g, x, grad),
        (1, 5) => weight_grad_n::<1, 5>(g, x, grad),
        (1, 7) => weight_grad_n::<1, 7>(g, x, grad),
        (2, 3) => weight_grad_n::<2, 3>(g, x, grad),
        (2, 5) => weight_grad_n::<2, 5>(g, x, grad),
        (2, 7) => weight_grad_n::<2, 7>(g, x, grad),
        shape => unreachable!("no narrow kernel for (outputs, kernel) {shape:?}"),
    }
}

/// [`weight_grad`] for `C` outputs and kernel `K`: per kernel row, the `C K` sums stay in
/// registers over every row of every image.
fn weight_grad_n<const C: usize, const K: usize>(g: &Geom, x: &[f32], grad: &[f32]) -> Vec<f32> {
    let wo_pad = g.wo.next_multiple_of(LANES);
    let row_len = wo_pad + K - 1;
    let hp = g.ho + K - 1;
    // The output gradient with rows zero-padded to whole lanes, so that padding adds nothing.
    let mut grad_rows = vec![0f32; g.batch * C * g.ho * wo_pad];
    grad_rows.par_chunks_mut(wo_pad).zip(grad.par_chunks(g.wo)).for_each(|(dst, src)| dst[..g.wo].copy_from_slice(src));
    let one_channel = Geom { cin: 1, ..*g };
    let per_channel: Vec<[[[f32; K]; K]; C]> = (0..g.cin)
        .into_par_iter()
        .map_init(
            || vec![0f32; g.batch * hp * row_len],
            |rows, ci| {
                flushing_denormals(|| {
                    for (b, dst) in rows.chunks_exact_mut(hp * row_len).enumerate() {
                        let image = &g.image(x, b)[ci * g.h * g.w..][..g.h * g.w];
                        pad_rows(&one_channel, image, -(g.pad as isize), hp, row_len, dst);
                    }
                    let mut sums = [[[0f32; K]; K]; C];
                    for kh in 0..K {
                        let mut acc = [[Lanes::splat(0.0); K]; C];
                        for b in 0..g.batch {
                            for oy in 0..g.ho {
                                let row = &rows[(b * hp + oy + kh) * row_len..][..row_len];
                                let grads: [&[f32]; C] = std::array::from_fn(|co| {
                                    &grad_rows[((b * C + co) * g.ho + oy) * wo_pad..][..wo_pad]
                                });
                                for x0 in (0..wo_pad).step_by(LANES) {
                                    let inputs: [Lanes; K] = std::array::from_fn(|kw| Lanes::load(&row[x0 + kw..]));
                                    for co in 0..C {
                                        let grad = Lanes::load(&grads[co][x0..]);
                                        for kw in 0..K {
                                            acc[co][kw] = grad.mul_add(inputs[kw], acc[co][kw]);
                                        }
                                    }
                                }
                            }
                        }
                        for co in 0..C {
                            for kw in 0..K {
                                sums[co][kh][kw] = acc[co][kw].sum();
                            }
                        }
                    }
                    sums
                })
            },
        )
        .collect();
    let kk = K * K;
    let mut dw = vec![0f32; C * g.cin * kk];
    for (ci, sums) in per_channel.iter().enumerate() {
        for (co, per_kh) in sums.iter().enumerate() {
            dw[(co * g.cin + ci) * kk..][..kk].copy_from_slice(per_kh.as_flattened());
        }
    }
    dw
}

/// Eight f32 lanes: one AVX2 register where the build has AVX2 and FMA (this workspace targets
/// x86-64-v3), plain arrays elsewhere. The auto-vectoriser does not keep arrays of sums in
/// registers across the loops above, so the kernels say it explicitly.
mod lanes {
    pub const LANES: usize = 8;

    #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
    mod imp {
        use std::arch::x86_64::*;

        // A path from the crate root: the layering scan reads `super::` as the file's parent.
        use crate::nn::ops::conv2d::narrow::lanes::LANES;

        #[derive(Clone, Copy)]
        pub struct Lanes(__m256);

        impl Lanes {
            #[inline(always)]
            pub fn splat(v: f32) -> Self {
                // SAFETY: the build enables AVX (the cfg of this module).
                Self(unsafe { _mm256_set1_ps(v) })
            }

            /// The first 8 values of `s` (panics if there are fewer).
            #[inline(always)]
            pub fn load(s: &[f32]) -> Self {
                let s = &s[..LANES];
                // SAFETY: `s` holds 8 readable f32; the load has no alignment requirement.
                Self(unsafe { _mm256_loadu_ps(s.as_ptr()) })
            }

            #[inline(always)]
            pub fn store(self, d: &mut [f32; LANES]) {
                // SAFETY: `d` holds 8 writable f32; the store has no alignment requirement.
                unsafe { _mm256_storeu_ps(d.as_mut_ptr(), self.0) }
            }

            /// `self b + c`, fused.
            #[inline(always)]
            pub fn mul_add(self, b: Self, c: Self) -> Self {
                // SAFETY: the build enables FMA (the cfg of this module).
                Self(unsafe { _mm256_fmadd_ps(self.0, b.0, c.0) })
            }

            /// The sum of the lanes, in a fixed order (as the portable version).
            #[inline(always)]
            pub fn sum(self) -> f32 {
                let mut d = [0f32; LANES];
                self.store(&mut d);
                d.iter().sum()
            }
        }
    }

    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
    mod imp {
        use crate::nn::ops::conv2d::narrow::lanes::LANES;

        #[derive(Clone, Copy)]
        pub struct Lanes([f32; LANES]);

        impl Lanes {
            #[inline(always)]
            pub fn splat(v: f32) -> Self {
                Self([v; LANES])
            }

            #[inline(always)]
            pub fn load(s: &[f32]) -> Self {
                Self(s[..LANES].try_into().expect("8 values"))
            }

            #[inline(always)]
            pub fn store(self, d: &mut [f32; LANES]) {
                *d = self.0;
            }

            #[inline(always)]
            pub fn mul_add(self, b: Self, c: Self) -> Self {
                Self(std::array::from_fn(|l| self.0[l].mul_add(b.0[l], c.0[l])))
            }

            #[inline(always)]
            pub fn sum(self) -> f32 {
                self.0.iter().sum()
            }
        }
    }

    pub use imp::Lanes;
}
