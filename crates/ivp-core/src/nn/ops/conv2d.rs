//! 2-D convolution on the CPU as a candle custom op, forward and backward, on the `gemm` crate.
//!
//! candle's own CPU convolution spends most of its time in a scalar im2col loop and computes the
//! input gradient with a `conv_transpose2d` that never calls gemm (ALGORITHMS.md §8). Here all three products
//! are gemm calls on *tiles*: a range of output pixels of one image (at least `MIN_TILE_PX`) and a
//! block of input channels, whose im2col matrix (`cb k k` rows by `px` pixels) is about
//! `TILE_BYTES` and stays in L2. A full-frame im2col buffer is never built (64 -> 64 channels 3x3
//! at 1080x1920 would need 4.8 GB).
//! - Forward: `out_tile += w_block im2col_tile`, summed over the channel blocks; the bias is the
//!   initial value of the output (a `CustomOp3`), so it costs no extra pass.
//! - Input gradient: for stride 1 with Cout <= Cin (the decoder, the depth head), a forward
//!   convolution of the output gradient with the flipped kernel; otherwise (stride 2, or Cout > Cin
//!   as in e1) `col2im(w_block^T grad_tile)`, a scatter-add.
//! - Weight gradient: `dw_block += grad_tile im2col_tile^T`; for narrow layers in sub-blocks of at
//!   most 256 outputs, for which gemm uses its dot-product kernels (see `weight_grad`).
//!
//! Parallelism: tiles are spread over the current rayon pool and each gemm runs single-threaded
//! (measured about twice as fast as a serial tile loop with gemm's own threading, whose im2col
//! copies then run on one thread). Every output value is computed by the same sequence of
//! floating-point operations whatever the number of threads, so results are bit-identical for any
//! pool size:
//! - forward: each output value belongs to exactly one tile;
//! - col2im: tiles scatter-add into overlapping input rows, so they run in two phases (even tiles,
//!   then odd tiles of each image); tiles of one phase touch disjoint input rows;
//! - weight gradient: the work items (channel block, chunk of consecutive tiles) are fixed by the
//!   shapes alone, each accumulates its partial sum in tile order, and the partials are added in
//!   chunk order.
//!
//! Subnormal floats: as training goes on, gradients of deep layers and of units that rarely fire
//! fall below f32's normal range (1.2e-38), and x86 processors handle subnormal operands in
//! microcode, many times slower. In the default recipe the gemm kernels ran 3x slower after 1000
//! steps than at the start (0.2 -> 0.4 s per step). Every gemm call therefore runs with FTZ and DAZ
//! set (subnormals read and written as zero) on its thread, restored afterwards: the results are
//! the same on any thread of any pool, and values that small carry nothing for training.

mod geom;
mod narrow;

use geom::{flushing_denormals, Geom, SharedMut};

use crate::nn::ops::{contiguous_values, profile};
use std::cell::RefCell;
use std::ops::Range;

use candle_core::{bail, CpuStorage, CustomOp2, CustomOp3, DType, Layout, Result, Shape, Tensor};
use gemm::Parallelism;
use rayon::prelude::*;

/// Target size of one im2col tile. Half the 1 MiB per-core L2 cache: the tile is written by the
/// im2col loop and read right away by gemm, while gemm's packed blocks take the other half.
const TILE_BYTES: usize = 512 << 10;

/// Fewest output pixels per tile: the gemm depth of the weight gradient and the number of pixels
/// per read of the weights in the forward pass. Layers with many taps get fewer input channels per
/// tile instead (channel blocks), not fewer pixels.
const MIN_TILE_PX: usize = 256;

/// Fewest parallel work items of the weight gradient: (channel block, chunk of tiles) pairs, each
/// with its own partial sum. A constant, not the thread count, so that the summation order is fixed.
const WGRAD_ITEMS: usize = 8;

/// Convolution of `x` (B, Cin, H, W) with `w` (Cout, Cin, k, k), plus `bias` (Cout) if given, with
/// zero padding; all f32 on the CPU. Output (B, Cout, Ho, Wo) with Ho = (H + 2 padding - k) / stride + 1,
/// as in PyTorch. Differentiable with respect to all three arguments; the input gradient is skipped
/// when `x` needs none (it is not a variable and does not depend on one).
pub fn conv2d(x: &Tensor, w: &Tensor, bias: Option<&Tensor>, stride: usize, padding: usize) -> Result<Tensor> {
    conv2d_with_tile(x, w, bias, stride, padding, false, TILE_BYTES)
}

/// `relu(conv2d(x, w, bias))` in one op. The ReLU costs no pass of its own in the forward, and in
/// the backward the output gradient is masked by `output > 0` once (candle's `relu` backward takes
/// four passes over the activation). The gradient at exactly 0 is 0, as in PyTorch.
pub fn conv2d_relu(x: &Tensor, w: &Tensor, bias: Option<&Tensor>, stride: usize, padding: usize) -> Result<Tensor> {
    conv2d_with_tile(x, w, bias, stride, padding, true, TILE_BYTES)
}

/// [`conv2d`] with a chosen tile size: tests use tiny tiles to exercise the tile seams.
fn conv2d_with_tile(
    x: &Tensor,
    w: &Tensor,
    bias: Option<&Tensor>,
    stride: usize,
    padding: usize,
    relu: bool,
    tile_bytes: usize,
) -> Result<Tensor> {
    for t in [Some(x), Some(w), bias].into_iter().flatten() {
        if t.dtype() != DType::F32 || !t.device().is_cpu() {
            bail!("conv2d: f32 tensors on the CPU expected, got {:?} on {:?}", t.dtype(), t.device());
        }
    }
    let (_, cin, h, wd) = x.dims4()?;
    let (cout, wcin, kh, kw) = w.dims4()?;
    if wcin != cin || kh != kw || kh == 0 || stride == 0 || h + 2 * padding < kh || wd + 2 * padding < kw {
        bail!("conv2d: input {:?}, kernel {:?}, stride {stride}, padding {padding}", x.dims(), w.dims());
    }
    let op = Conv2d { stride, padding, relu, tile_bytes };
    // The kernels read plain row-major buffers; `contiguous` is free when the tensor already is.
    let (x, w) = (x.contiguous()?, w.contiguous()?);
    match bias {
        None => x.apply_op2(&w, op),
        Some(b) => {
            if b.dims1()? != cout {
                bail!("conv2d: bias {:?} for {cout} output channels", b.dims());
            }
            x.apply_op3(&w, &b.contiguous()?, op)
        }
    }
}

/// How a product is cut: tiles of `px` output pixels of one image, input channels in blocks of `cb`.
/// An im2col tile is `cb k k` rows by `px` columns.
#[derive(Clone, Copy, Debug)]
struct Tiling {
    px: usize,
    cb: usize,
}

impl Geom {
    /// Tiles of about `tile_bytes` of im2col: all channels at once if that leaves at least
    /// [`MIN_TILE_PX`] pixels, else that many pixels and fewer channels. Tiles have at least
    /// `min_rows` output rows. Depends on the shapes only, never on the thread count.
    fn tiling(&self, tile_bytes: usize, min_rows: usize) -> Tiling {
        let (p, kk) = (self.pixels(), self.k * self.k);
        // (Tiny `tile_bytes`, in tests, give tiny tiles.)
        let min_px = MIN_TILE_PX.min(tile_bytes / (4 * kk));
        let wanted = (tile_bytes / (4 * self.taps().max(1))).max(min_px).max(1);
        // Equal tiles rather than full ones and a remainder; a multiple of 16 (one AVX-512 register).
        let n = p.div_ceil(wanted);
        let px = p.div_ceil(n).next_multiple_of(16).max(min_rows * self.wo).min(p);
        let cb = (tile_bytes / (4 * kk * px.max(1))).min(self.cin).max(1);
        Tiling { px, cb: self.cin.div_ceil(self.cin.div_ceil(cb).max(1)).max(1) }
    }

    /// The pixel tiles of all images, as (image, pixel range), image after image.
    fn pixel_tiles(&self, t: Tiling) -> Vec<(usize, Range<usize>)> {
        let p = self.pixels();
        (0..self.batch).flat_map(|b| (0..p).step_by(t.px).map(move |p0| (b, p0..(p0 + t.px).min(p)))).collect()
    }

    /// The input channel blocks.
    fn channel_blocks(&self, t: Tiling) -> Vec<Range<usize>> {
        (0..self.cin).step_by(t.cb).map(|c| c..(c + t.cb).min(self.cin)).collect()
    }
}

/// Calls `f(oy, ox0, j0, len)` for each piece of an output row inside the pixel range `px`: the
/// pixels `j0..j0 + len` of the range are row `oy`, columns `ox0..ox0 + len`.
/// (im2col calls this once per kernel tap and the closure once per row of a small image: one
/// division per call, not per piece.)
#[inline]
fn for_each_row_piece(wo: usize, px: Range<usize>, mut f: impl FnMut(usize, usize, usize, usize)) {
    let (mut p, mut oy, mut ox0) = (px.start, px.start / wo, px.start % wo);
    while p < px.end {
        let len = (wo - ox0).min(px.end - p);
        f(oy, ox0, p - px.start, len);
        p += len;
        (oy, ox0) = (oy + 1, 0);
    }
}

/// The `j` in `0..len` for which `0 <= ix0 + j s < n`: which pixels of a row piece read inside the image.
#[inline]
fn inside(len: usize, n: usize, ix0: isize, s: usize) -> Range<usize> {
    if s == 1 {
        let lo = (-ix0).clamp(0, len as isize);
        let hi = (n as isize - ix0).clamp(lo, len as isize);
        return lo as usize..hi as usize;
    }
    let s = s as isize;
    let lo = if ix0 >= 0 { 0 } else { (-ix0 + s - 1) / s };
    let last = n as isize - 1 - ix0;
    let hi = if last < 0 { 0 } else { (last / s + 1).min(len as isize) };
    (lo.min(hi) as usize)..(hi as usize)
}

/// The im2col tile of image `x` (Cin, H, W) for the channels `chans` and output pixels `px`:
/// `col[r][j]` with r = ((ci - chans.start) k + kh) k + kw is the input value that pixel
/// `px.start + j` reads through tap (ci, kh, kw), 0 in the padding. Row-major, `rows x px.len()`;
/// each row is a shifted (for stride 2, strided) copy of pieces of input rows.
fn im2col(g: &Geom, x: &[f32], chans: Range<usize>, px: Range<usize>, col: &mut [f32]) {
    let (n, k, s) = (px.len(), g.k, g.stride);
    let planes = x.chunks_exact(g.h * g.w).skip(chans.start).take(chans.len());
    for (c, plane) in planes.enumerate() {
        for kh in 0..k {
            for kw in 0..k {
                let row = &mut col[((c * k + kh) * k + kw) * n..][..n];
                for_each_row_piece(g.wo, px.clone(), |oy, ox0, j0, len| {
                    let dst = &mut row[j0..j0 + len];
                    let iy = (oy * s + kh) as isize - g.pad as isize;
                    if iy < 0 || iy >= g.h as isize {
                        dst.fill(0.0);
                        return;
                    }
                    let src = &plane[iy as usize * g.w..][..g.w];
                    let ix0 = (ox0 * s + kw) as isize - g.pad as isize;
                    let ok = inside(len, g.w, ix0, s);
                    dst[..ok.start].fill(0.0);
                    dst[ok.end..].fill(0.0);
                    if ok.is_empty() {
                        return;
                    }
                    let first = (ix0 + (ok.start * s) as isize) as usize;
                    let src = &src[first..first + (ok.len() - 1) * s + 1];
                    match s {
                        1 => dst[ok].copy_from_slice(src),
                        2 => {
                            // Pairs of the source row: vectorised as interleaved loads.
                            let (last, dst) = dst[ok].split_last_mut().expect("not empty");
                            dst.iter_mut().zip(src.chunks_exact(2)).for_each(|(d, pair)| *d = pair[0]);
                            *last = src[src.len() - 1];
                        }
                        _ => dst[ok].iter_mut().enumerate().for_each(|(j, d)| *d = src[s * j]),
                    }
                });
            }
        }
    }
}

/// The adjoint of [`im2col`]: adds each entry of `col` (same layout) to the input pixel of image `dx`
/// (Cin, H, W) it stands for.
///
/// # Safety
/// `dx` points to a whole image (Cin H W values), and no other thread reads or writes the input rows
/// that the output rows of `px` read (rows `oy s - pad .. oy s - pad + k`) during the call.
unsafe fn col2im_add(g: &Geom, dx: *mut f32, chans: Range<usize>, px: Range<usize>, col: &[f32]) {
    let (n, k, s) = (px.len(), g.k, g.stride);
    for (c, ci) in chans.enumerate() {
        for kh in 0..k {
            for kw in 0..k {
                let row = &col[((c * k + kh) * k + kw) * n..][..n];
                for_each_row_piece(g.wo, px.clone(), |oy, ox0, j0, len| {
                    let iy = (oy * s + kh) as isize - g.pad as isize;
                    if iy < 0 || iy >= g.h as isize {
                        return;
                    }
                    let ix0 = (ox0 * s + kw) as isize - g.pad as isize;
                    let ok = inside(len, g.w, ix0, s);
                    if ok.is_empty() {
                        return;
                    }
                    // SAFETY: a row of the image, which the caller lets this thread alone use.
                    let dst = unsafe { std::slice::from_raw_parts_mut(dx.add((ci * g.h + iy as usize) * g.w), g.w) };
                    let first = (ix0 + (ok.start * s) as isize) as usize;
                    let src = &row[j0 + ok.start..j0 + ok.end];
                    let dst = &mut dst[first..first + (src.len() - 1) * s + 1];
                    match s {
                        1 => dst.iter_mut().zip(src).for_each(|(d, v)| *d += v),
                        // Pairs of the row: vectorised as interleaved loads and stores.
                        2 => {
                            let (last, src) = src.split_last().expect("not empty");
                            dst.chunks_exact_mut(2).zip(src).for_each(|(pair, v)| pair[0] += v);
                            dst[dst.len() - 1] += last;
                        }
                        _ => src.iter().enumerate().for_each(|(j, v)| dst[s * j] += v),
                    }
                });
            }
        }
    }
}

/// A matrix operand for [`matmul`]: element (i, j) is at `ptr + i rs + j cs`.
#[derive(Clone, Copy)]
struct Mat {
    ptr: *const f32,
    rs: usize,
    cs: usize,
}

impl Mat {
    fn new(ptr: *const f32, rs: usize, cs: usize) -> Self {
        Self { ptr, rs, cs }
    }
}

/// `dst (m x n) = [dst +] lhs (m x k) rhs (k x n)` on the calling thread: the callers spread tiles
/// over the threads instead, which keeps the im2col copies parallel too. Subnormal operands and
/// results are flushed to zero (see the module documentation).
///
/// # Safety
/// The three matrices are valid for their shapes and strides, `dst` is writable and overlaps neither.
unsafe fn matmul(m: usize, n: usize, k: usize, dst: Mat, accumulate: bool, lhs: Mat, rhs: Mat) {
    // SAFETY: as promised by the caller. `read_dst = false` makes gemm ignore the old dst entirely.
    flushing_denormals(|| unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.ptr as *mut f32,
            dst.cs as isize,
            dst.rs as isize,
            accumulate,
            lhs.ptr,
            lhs.cs as isize,
            lhs.rs as isize,
            rhs.ptr,
            rhs.cs as isize,
            rhs.rs as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        )
    })
}

/// `out (m x n) += lhs (m x k) rhs (k x n)` on the calling thread, each a row-major matrix given
/// as a slice that starts at its first element and its row stride (which may exceed its width:
/// a block of a larger matrix). The operands' rows may overlap (a stride below the width reads
/// a sliding window of one line); the output's may not.
pub(crate) fn add_product(
    (m, n, k): (usize, usize, usize),
    (lhs, lhs_stride): (&[f32], usize),
    (rhs, rhs_stride): (&[f32], usize),
    (out, out_stride): (&mut [f32], usize),
) {
    if m == 0 || n == 0 {
        return;
    }
    let fits = |len: usize, rows: usize, cols: usize, stride: usize| {
        rows == 0 || cols == 0 || len >= (rows - 1) * stride + cols
    };
    assert!(
        fits(lhs.len(), m, k, lhs_stride)
            && fits(rhs.len(), k, n, rhs_stride)
            && fits(out.len(), m, n, out_stride)
            && out_stride >= n,
        "add_product: the slices do not hold the matrices"
    );
    // SAFETY: each slice holds its matrix with these strides (checked above), and `out` is
    // borrowed mutably, so it overlaps neither operand.
    unsafe {
        let (dst, a, b) = (
            Mat::new(out.as_mut_ptr(), out_stride, 1),
            Mat::new(lhs.as_ptr(), lhs_stride, 1),
            Mat::new(rhs.as_ptr(), rhs_stride, 1),
        );
        matmul(m, n, k, dst, true, a, b)
    }
}

thread_local! {
    /// The tile buffer of each thread, kept between calls: allocating a few MB per tile costs page faults.
    static SCRATCH: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` on this thread's scratch buffer of `len` values (stale contents). `f` must not re-enter.
fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [f32]) -> R) -> R {
    SCRATCH.with(|s| {
        let mut s = s.borrow_mut();
        if s.len() < len {
            s.resize(len, 0.0);
        }
        f(&mut s[..len])
    })
}

/// Sum with 16 independent lanes: vectorised, and its order depends on the length only.
fn sum(v: &[f32]) -> f32 {
    let mut acc = [0f32; 16];
    let mut chunks = v.chunks_exact(16);
    for c in chunks.by_ref() {
        for (a, x) in acc.iter_mut().zip(c) {
            *a += x;
        }
    }
    acc.iter().sum::<f32>() + chunks.remainder().iter().sum::<f32>()
}

/// Forward: `out[b, co, p] = bias[co] + sum_r w[co, r] im2col(x[b])[r, p]`, on im2col tiles, or by
/// the direct kernels of [`narrow`] for stride 1 with few outputs.
fn forward(g: &Geom, x: &[f32], w: &[f32], bias: Option<&[f32]>, tile_bytes: usize) -> Vec<f32> {
    if narrow::applies_forward(g) {
        narrow::forward(g, x, w, bias)
    } else {
        tiled_forward(g, x, w, bias, tile_bytes)
    }
}

/// [`forward`] on im2col tiles: per pixel tile, one gemm per channel block, accumulated in block order.
fn tiled_forward(g: &Geom, x: &[f32], w: &[f32], bias: Option<&[f32]>, tile_bytes: usize) -> Vec<f32> {
    let (taps, p, kk) = (g.taps(), g.pixels(), g.k * g.k);
    let t = g.tiling(tile_bytes, 1);
    let blocks = g.channel_blocks(t);
    let mut out = vec![0f32; g.batch * g.cout * p];
    let out_ptr = SharedMut(out.as_mut_ptr());
    g.pixel_tiles(t).into_par_iter().for_each(|(b, px)| {
        let n = px.len();
        // This tile's part of the output: Cout rows of n pixels, p apart. No other tile writes it.
        let dst = out_ptr.at(b * g.cout * p + px.start);
        if let Some(bias) = bias {
            for (co, &v) in bias.iter().enumerate() {
                // SAFETY: row co of this tile's part.
                unsafe { std::slice::from_raw_parts_mut(dst.add(co * p), n) }.fill(v);
            }
        }
        with_scratch(t.cb * kk * n, |col| {
            for (i, chans) in blocks.iter().enumerate() {
                let rows = chans.len() * kk;
                im2col(g, g.image(x, b), chans.clone(), px.clone(), col);
                // SAFETY: w's columns of the block are Cout x rows, col rows x n, dst Cout x n inside `out`.
                unsafe {
                    matmul(
                        g.cout,
                        n,
                        rows,
                        Mat::new(dst, p, 1),
                        i > 0 || bias.is_some(),
                        Mat::new(w[chans.start * kk..].as_ptr(), taps, 1),
                        Mat::new(col.as_ptr(), n, 1),
                    )
                };
            }
        });
    });
    out
}

/// Input gradient, the transposed convolution of `grad` (B, Cout, Ho, Wo).
fn input_grad(g: &Geom, grad: &[f32], w: &[f32], tile_bytes: usize) -> Vec<f32> {
    if g.stride == 1 && g.cout <= g.cin && g.pad < g.k {
        // With stride 1 it is a convolution of grad with the kernel flipped and its channel axes
        // swapped, padded by k - 1 - pad: a gemm of depth Cout k k writing dx once, much cheaper
        // than col2im's depth Cout (2 for the last layer) when Cout <= Cin.
        let gt = Geom::new((g.batch, g.cout, g.ho, g.wo), g.cin, g.k, 1, g.k - 1 - g.pad);
        debug_assert_eq!((gt.ho, gt.wo), (g.h, g.w));
        let kk = g.k * g.k;
        let mut wt = vec![0f32; w.len()];
        for (co, wc) in w.chunks_exact(g.cin * kk).enumerate() {
            for (ci, taps) in wc.chunks_exact(kk).enumerate() {
                for (i, &v) in taps.iter().rev().enumerate() {
                    wt[(ci * g.cout + co) * kk + i] = v;
                }
            }
        }
        return forward(&gt, grad, &wt, None, tile_bytes);
    }
    col2im_grad(g, grad, w, tile_bytes)
}

/// Input gradient as `dx[b] = col2im(w^T grad[b])`, tile by tile.
fn col2im_grad(g: &Geom, grad: &[f32], w: &[f32], tile_bytes: usize) -> Vec<f32> {
    let (taps, p, kk) = (g.taps(), g.pixels(), g.k * g.k);
    let image_len = g.cin * g.h * g.w;
    let mut dx = vec![0f32; g.batch * image_len];
    let dx_ptr = SharedMut(dx.as_mut_ptr());
    // Tiles of at least k output rows: then tiles i and i + 2 of an image write input rows at
    // least one row apart, and each phase below can run its tiles in parallel.
    let t = g.tiling(tile_bytes, g.k);
    let blocks = g.channel_blocks(t);
    let tiles = g.pixel_tiles(t);
    let per_image = tiles.len() / g.batch.max(1);
    for phase in 0..2 {
        tiles.par_iter().enumerate().filter(|(i, _)| (i % per_image) % 2 == phase).for_each(|(_, (b, px))| {
            let n = px.len();
            with_scratch(t.cb * kk * n, |col| {
                for chans in &blocks {
                    let rows = chans.len() * kk;
                    // SAFETY: w^T's rows of the block are rows x Cout (w read column-wise), the grad
                    // tile Cout x n, col rows x n.
                    unsafe {
                        matmul(
                            rows,
                            n,
                            g.cout,
                            Mat::new(col.as_mut_ptr(), n, 1),
                            false,
                            Mat::new(w[chans.start * kk..].as_ptr(), 1, taps),
                            Mat::new(grad[b * g.cout * p + px.start..].as_ptr(), p, 1),
                        )
                    };
                    // SAFETY: tiles of one phase write disjoint input rows (see above); images are disjoint.
                    unsafe { col2im_add(g, dx_ptr.at(b * image_len), chans.clone(), px.clone(), col) };
                }
            });
        });
    }
    dx
}

/// Weight gradient `dw (Cout x taps)`: on im2col tiles, or by the direct kernels of [`narrow`] for
/// stride 1 with few outputs.
fn weight_grad(g: &Geom, x: &[f32], grad: &[f32], tile_bytes: usize) -> Vec<f32> {
    if narrow::applies(g) {
        narrow::weight_grad(g, x, grad)
    } else {
        tiled_weight_grad(g, x, grad, tile_bytes)
    }
}

/// [`weight_grad`] as the sum over pixel tiles of `grad_tile im2col(x)_tile^T`.
///
/// Work items are (channel block, chunk of consecutive tiles); each accumulates a partial sum of its
/// block's columns in tile order, and the partials of a block are added in chunk order. With at
/// least [`WGRAD_ITEMS`] items both threads stay busy even for a single block (e1: 3 channels).
fn tiled_weight_grad(g: &Geom, x: &[f32], grad: &[f32], tile_bytes: usize) -> Vec<f32> {
    let (taps, p, kk) = (g.taps(), g.pixels(), g.k * g.k);
    let t = g.tiling(tile_bytes, 1);
    let blocks = g.channel_blocks(t);
    let tiles = g.pixel_tiles(t);
    if blocks.is_empty() || tiles.is_empty() {
        return vec![0f32; g.cout * taps];
    }
    let chunks = WGRAD_ITEMS.div_ceil(blocks.len()).min(tiles.len());
    let items: Vec<(usize, usize)> = (0..blocks.len()).flat_map(|bl| (0..chunks).map(move |c| (bl, c))).collect();
    let partials: Vec<Vec<f32>> = items
        .into_par_iter()
        .map(|(bl, c)| {
            let chans = blocks[bl].clone();
            let rows = chans.len() * kk;
            let mut acc = vec![0f32; g.cout * rows];
            for (b, px) in &tiles[c * tiles.len() / chunks..(c + 1) * tiles.len() / chunks] {
                let n = px.len();
                with_scratch(rows * n, |col| {
                    im2col(g, g.image(x, *b), chans.clone(), px.clone(), col);
                    // Both operands are contiguous along the pixels (the depth). For up to 256
                    // outputs per call gemm then uses its dot-product kernels, several times faster
                    // for narrow layers than its packed kernels, which need col transposed; wide
                    // layers do better with one packed call.
                    let sub = if g.cout < 128 { (256 / g.cout).max(1) } else { rows };
                    for r0 in (0..rows).step_by(sub) {
                        // SAFETY: grad tile Cout x n, col^T n x rows (col read column-wise), acc
                        // Cout x rows; columns r0.. of the last two.
                        unsafe {
                            matmul(
                                g.cout,
                                sub.min(rows - r0),
                                n,
                                Mat::new(acc[r0..].as_mut_ptr(), rows, 1),
                                true,
                                Mat::new(grad[b * g.cout * p + px.start..].as_ptr(), p, 1),
                                Mat::new(col[r0 * n..].as_ptr(), 1, n),
                            )
                        };
                    }
                });
            }
            acc
        })
        .collect();
    let mut dw = vec![0f32; g.cout * taps];
    dw.par_chunks_mut(taps).enumerate().for_each(|(co, dst)| {
        for (chans, parts) in blocks.iter().zip(partials.chunks_exact(chunks)) {
            let rows = chans.len() * kk;
            let dst = &mut dst[chans.start * kk..][..rows];
            for part in parts {
                for (d, v) in dst.iter_mut().zip(&part[co * rows..][..rows]) {
                    *d += v;
                }
            }
        }
    });
    dw
}

/// Bias gradient: the sum of `grad` (B, Cout, Ho, Wo) over all but the channel axis.
fn bias_grad(g: &Geom, grad: &[f32]) -> Vec<f32> {
    let p = g.pixels();
    (0..g.cout).into_par_iter().map(|co| (0..g.batch).map(|b| sum(&grad[(b * g.cout + co) * p..][..p])).sum()).collect()
}

/// The forward op on (x, w) or (x, w, bias).
#[derive(Clone, Copy, Debug)]
struct Conv2d {
    stride: usize,
    padding: usize,
    /// Apply a ReLU to the output (see [`conv2d_relu`]).
    relu: bool,
    tile_bytes: usize,
}

impl Conv2d {
    fn geom(&self, x: &Layout, w: &Layout) -> Result<Geom> {
        let (cout, _, k, _) = w.shape().dims4()?;
        Ok(Geom::new(x.shape().dims4()?, cout, k, self.stride, self.padding))
    }

    fn cpu(
        &self,
        x: (&CpuStorage, &Layout),
        w: (&CpuStorage, &Layout),
        bias: Option<(&CpuStorage, &Layout)>,
    ) -> Result<(CpuStorage, Shape)> {
        let g = self.geom(x.1, w.1)?;
        let bias = bias.map(|(s, l)| contiguous_values(s, l, "conv2d")).transpose()?;
        let mut out = forward(
            &g,
            contiguous_values(x.0, x.1, "conv2d")?,
            contiguous_values(w.0, w.1, "conv2d")?,
            bias,
            self.tile_bytes,
        );
        if self.relu {
            out.par_chunks_mut(1 << 14).for_each(|c| c.iter_mut().for_each(|v| *v = v.max(0.0)));
        }
        Ok((CpuStorage::F32(out), Shape::from((g.batch, g.cout, g.ho, g.wo))))
    }

    /// Gradients of (x, w, bias), each only if that argument needs one; all computed by the kernels above.
    fn backward(
        &self,
        x: &Tensor,
        w: &Tensor,
        bias: Option<&Tensor>,
        output: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let grad = match self.relu {
            true => grad.contiguous()?.apply_op2_no_bwd(&output.contiguous()?, &ReluMask)?,
            false => grad.contiguous()?,
        };
        let (_, _, h, wd) = x.dims4()?;
        let (cout, cin, k, _) = w.dims4()?;
        let (stride, padding, tile_bytes) = (self.stride, self.padding, self.tile_bytes);
        let dx = match x.track_op() {
            true => Some(grad.apply_op2_no_bwd(w, &Conv2dInputGrad { stride, padding, h, w: wd, tile_bytes })?),
            false => None,
        };
        let weights = w.track_op();
        let bias = bias.is_some_and(Tensor::track_op);
        if !weights && !bias {
            return Ok((dx, None, None));
        }
        let t = x.apply_op2_no_bwd(&grad, &Conv2dWeightGrad { stride, padding, k, weights, bias, tile_bytes })?;
        let taps = cin * k * k;
        let dw = match (weights, bias) {
            (false, _) => None,
            (true, false) => Some(t.reshape(w.shape())?),
            (true, true) => Some(t.narrow(1, 0, taps)?.reshape(w.shape())?),
        };
        let db = match bias {
            true => Some(t.narrow(1, t.dim(1)? - 1, 1)?.reshape(cout)?),
            false => None,
        };
        Ok((dx, dw, db))
    }
}

impl CustomOp2 for Conv2d {
    fn name(&self) -> &'static str {
        "ivp-conv2d"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        profile::timed("conv2d forward", || self.cpu((s1, l1), (s2, l2), None))
    }

    fn bwd(&self, x: &Tensor, w: &Tensor, res: &Tensor, grad: &Tensor) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let (dx, dw, _) = self.backward(x, w, None, res, grad)?;
        Ok((dx, dw))
    }
}

impl CustomOp3 for Conv2d {
    fn name(&self) -> &'static str {
        "ivp-conv2d-bias"
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
        profile::timed("conv2d forward", || self.cpu((s1, l1), (s2, l2), Some((s3, l3))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        bias: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        self.backward(x, w, Some(bias), res, grad)
    }
}

/// The gradient through a ReLU, on (grad, output): `grad` where `output > 0`, else 0.
#[derive(Clone, Copy, Debug)]
struct ReluMask;

impl CustomOp2 for ReluMask {
    fn name(&self) -> &'static str {
        "ivp-relu-mask"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        if l1.dims() != l2.dims() {
            bail!("conv2d relu gradient: grad {:?}, output {:?}", l1.dims(), l2.dims());
        }
        let (grad, out) = (contiguous_values(s1, l1, "conv2d")?, contiguous_values(s2, l2, "conv2d")?);
        let mut masked = vec![0f32; grad.len()];
        const CHUNK: usize = 1 << 14;
        masked.par_chunks_mut(CHUNK).zip(grad.par_chunks(CHUNK)).zip(out.par_chunks(CHUNK)).for_each(|((m, g), o)| {
            for ((m, g), o) in m.iter_mut().zip(g).zip(o) {
                *m = if *o > 0.0 { *g } else { 0.0 };
            }
        });
        Ok((CpuStorage::F32(masked), l1.shape().clone()))
    }
}

/// Input gradient op on (grad (B, Cout, Ho, Wo), w): dx (B, Cin, H, W). H and W are given because
/// with stride 2 several input sizes have the same output size.
#[derive(Clone, Copy, Debug)]
struct Conv2dInputGrad {
    stride: usize,
    padding: usize,
    h: usize,
    w: usize,
    tile_bytes: usize,
}

impl CustomOp2 for Conv2dInputGrad {
    fn name(&self) -> &'static str {
        "ivp-conv2d-input-grad"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (batch, cout, ho, wo) = l1.shape().dims4()?;
        let (wcout, cin, k, _) = l2.shape().dims4()?;
        let g = Geom::new((batch, cin, self.h, self.w), cout, k, self.stride, self.padding);
        if (g.ho, g.wo) != (ho, wo) || wcout != cout {
            bail!("conv2d input gradient: grad {:?} for kernel {:?}", l1.dims(), l2.dims());
        }
        let (grad, w) = (contiguous_values(s1, l1, "conv2d")?, contiguous_values(s2, l2, "conv2d")?);
        let dx = profile::timed("conv2d input gradient", || input_grad(&g, grad, w, self.tile_bytes));
        Ok((CpuStorage::F32(dx), Shape::from((batch, cin, self.h, self.w))))
    }
}

/// Weight/bias gradient op on (x, grad): (Cout, Cin k k [+ 1]), see [`weight_grad`].
#[derive(Clone, Copy, Debug)]
struct Conv2dWeightGrad {
    stride: usize,
    padding: usize,
    k: usize,
    weights: bool,
    bias: bool,
    tile_bytes: usize,
}

impl CustomOp2 for Conv2dWeightGrad {
    fn name(&self) -> &'static str {
        "ivp-conv2d-weight-grad"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (_, cout, ho, wo) = l2.shape().dims4()?;
        let g = Geom::new(l1.shape().dims4()?, cout, self.k, self.stride, self.padding);
        if (g.ho, g.wo) != (ho, wo) || l1.dims()[0] != l2.dims()[0] {
            bail!("conv2d weight gradient: input {:?}, grad {:?}", l1.dims(), l2.dims());
        }
        let (x, grad) = (contiguous_values(s1, l1, "conv2d")?, contiguous_values(s2, l2, "conv2d")?);
        let (dw, db) = profile::timed("conv2d weight gradient", || {
            let dw = if self.weights { weight_grad(&g, x, grad, self.tile_bytes) } else { Vec::new() };
            let db = if self.bias { bias_grad(&g, grad) } else { Vec::new() };
            (dw, db)
        });
        // Row co: the weight gradients of output channel co, then its bias gradient.
        let cols = dw.len() / cout + db.len() / cout;
        let mut out = Vec::with_capacity(cout * cols);
        for co in 0..cout {
            out.extend_from_slice(&dw[dw.len() / cout * co..][..dw.len() / cout]);
            out.extend_from_slice(&db[db.len() / cout * co..][..db.len() / cout]);
        }
        Ok((CpuStorage::F32(out), Shape::from((cout, cols))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::*;
    use candle_core::{Device, Var};

    /// max |a - b| / max(1, max |b|)
    fn rel_err(a: &Tensor, b: &Tensor) -> f32 {
        assert_eq!(a.dims(), b.dims());
        let (a, b) = (flat(a), flat(b));
        let scale = b.iter().fold(1f32, |m, v| m.max(v.abs()));
        a.iter().zip(&b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
    }

    /// candle's own convolution plus bias: the reference.
    fn candle_conv(x: &Tensor, w: &Tensor, bias: &Tensor, stride: usize, padding: usize) -> Tensor {
        let y = x.conv2d(w, padding, stride, 1, 1).unwrap();
        y.broadcast_add(&bias.reshape((1, (), 1, 1)).unwrap()).unwrap()
    }

    /// (batch, cin, cout, h, w) of the small test cases: odd sizes, single channels, batch 2.
    /// One and two outputs at stride 1 take the direct kernels of `narrow`; 70 columns are two of
    /// their blocks.
    const SMALL: [(usize, usize, usize, usize, usize); 5] =
        [(2, 3, 4, 9, 7), (1, 1, 1, 13, 11), (2, 5, 3, 8, 13), (1, 2, 6, 7, 7), (2, 3, 2, 9, 70)];

    #[test]
    fn forward_matches_candle() {
        for k in [3, 5, 7] {
            for stride in [1, 2, 3] {
                for (i, &(b, cin, cout, h, w)) in SMALL.iter().enumerate() {
                    let seed = (k * 100 + stride * 10 + i) as u64;
                    let x = random(&[b, cin, h, w], seed);
                    let wt = random(&[cout, cin, k, k], seed + 1);
                    let bias = random(&[cout], seed + 2);
                    for padding in [k / 2, 0, k / 2 + 1] {
                        if h + 2 * padding < k || w + 2 * padding < k {
                            continue;
                        }
                        let want = candle_conv(&x, &wt, &bias, stride, padding);
                        // Default tiles, and tiles of 16 pixels to exercise the seams.
                        for tile in [TILE_BYTES, 1] {
                            let got = conv2d_with_tile(&x, &wt, Some(&bias), stride, padding, false, tile).unwrap();
                            let err = rel_err(&got, &want);
                            assert!(err < 1e-4, "k{k} s{stride} p{padding} {:?} tile {tile}: {err}", x.dims());
                        }
                        let no_bias = conv2d(&x, &wt, None, stride, padding).unwrap();
                        let want = x.conv2d(&wt, padding, stride, 1, 1).unwrap();
                        assert!(rel_err(&no_bias, &want) < 1e-4);
                    }
                }
            }
        }
    }

    #[test]
    fn subnormal_values_are_flushed_inside_the_products_only() {
        let tiny = f32::MIN_POSITIVE / 4.0;
        assert!(tiny != 0.0 && !tiny.is_normal());
        let x = Tensor::full(tiny, (1, 2, 5, 6), &Device::Cpu).unwrap();
        let w = Tensor::ones((3, 2, 3, 3), DType::F32, &Device::Cpu).unwrap();
        // One thread, so that the checks below run on the thread that ran the products.
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        pool.install(|| {
            // Read as zero by the products: exactly zero, where exact arithmetic gives up to 18 tiny.
            let y = conv2d(&x, &w, None, 1, 1).unwrap();
            assert!(flat(&y).iter().all(|&v| v == 0.0), "{:?}", &flat(&y)[..6]);
            let (a, b) = (std::hint::black_box(tiny), std::hint::black_box(0.5f32));
            assert!(a * b != 0.0, "the thread's floating-point mode is restored");
            // Normal values keep their products.
            let y = conv2d(&(&x * 1e30).unwrap(), &w, None, 1, 1).unwrap();
            assert!((flat(&y)[7] / (18.0 * tiny * 1e30) - 1.0).abs() < 1e-5);
            // The direct kernels of narrow layers flush them too.
            let one_output = w.narrow(0, 0, 1).unwrap();
            let y = conv2d(&x, &one_output, None, 1, 1).unwrap();
            assert!(flat(&y).iter().all(|&v| v == 0.0), "{:?}", &flat(&y)[..6]);
            assert!(a * b != 0.0, "the thread's floating-point mode is restored");
        });
    }

    #[test]
    fn empty_batch_gives_empty_output_and_gradients() {
        let x = Var::from_tensor(&Tensor::zeros((0, 2, 9, 9), DType::F32, &Device::Cpu).unwrap()).unwrap();
        let w = Var::from_tensor(&random(&[3, 2, 3, 3], 2)).unwrap();
        let b = Var::from_tensor(&random(&[3], 3)).unwrap();
        let y = conv2d(&x, &w, Some(&b), 2, 1).unwrap();
        assert_eq!(y.dims(), [0, 3, 5, 5]);
        let g = y.sum_all().unwrap().backward().unwrap();
        assert_eq!(flat(g.get(&w).unwrap()), vec![0f32; 54]);
        assert_eq!(flat(g.get(&b).unwrap()), vec![0f32; 3]);
    }

    #[test]
    fn strided_input_is_accepted() {
        let x = random(&[1, 2, 9, 11], 5).transpose(2, 3).unwrap(); // (1, 2, 11, 9), not contiguous
        let w = random(&[3, 2, 3, 3], 6);
        let want = x.contiguous().unwrap().conv2d(&w, 1, 1, 1, 1).unwrap();
        assert!(rel_err(&conv2d(&x, &w, None, 1, 1).unwrap(), &want) < 1e-4);
    }

    #[test]
    fn fused_relu_equals_conv_then_relu_forward_and_backward() {
        for (k, stride, (batch, cin, cout, h, w)) in
            [(3, 1, (2, 3, 4, 9, 7)), (5, 2, (1, 2, 3, 11, 8)), (7, 1, (2, 1, 2, 6, 5))]
        {
            let seed = (k * 100 + stride) as u64;
            let x = Var::from_tensor(&random(&[batch, cin, h, w], seed)).unwrap();
            let wt = Var::from_tensor(&random(&[cout, cin, k, k], seed + 1)).unwrap();
            let b = Var::from_tensor(&random(&[cout], seed + 2)).unwrap();
            let fused = conv2d_relu(&x, &wt, Some(&b), stride, k / 2).unwrap();
            let plain = conv2d(&x, &wt, Some(&b), stride, k / 2).unwrap().relu().unwrap();
            assert_eq!(flat(&fused), flat(&plain));
            assert!(flat(&fused).contains(&0.0) && flat(&fused).iter().any(|v| *v > 0.0));
            let r = random(fused.dims(), seed + 3);
            let grads = |y: Tensor| {
                let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                [&x, &wt, &b].map(|v| flat(g.get(v).unwrap()))
            };
            let (a, b2) = (grads(fused), grads(plain));
            for (ga, gb) in a.iter().zip(&b2) {
                let scale = gb.iter().fold(1f32, |m, v| m.max(v.abs()));
                let worst = ga.iter().zip(gb).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
                assert!(worst <= 1e-5 * scale, "k {k} stride {stride}: {worst}");
            }
        }
    }

    /// Gradients of L = sum(conv2d(x, w, b) * r) by our backward.
    fn our_grads(x: &Var, w: &Var, b: &Var, r: &Tensor, stride: usize, tile: usize) -> [Tensor; 3] {
        let y = conv2d_with_tile(x, w, Some(b), stride, w.dim(2).unwrap() / 2, false, tile).unwrap();
        let g = (y * r).unwrap().sum_all().unwrap().backward().unwrap();
        [x, w, b].map(|v| g.get(v).unwrap().clone())
    }

    #[test]
    fn gradients_match_finite_differences() {
        // L is linear in each argument, so central differences are exact up to rounding.
        let eps = 0.5f32;
        for (k, stride, (batch, cin, cout, h, w)) in [
            (3, 1, (2, 2, 3, 5, 7)),
            (3, 2, (2, 2, 3, 7, 5)),
            (5, 1, (1, 2, 2, 7, 6)),
            (7, 1, (2, 3, 1, 9, 8)),
            (5, 2, (2, 1, 3, 9, 7)),
            (3, 3, (1, 2, 2, 8, 7)),
        ] {
            let seed = (k * 10 + stride) as u64;
            let x = Var::from_tensor(&random(&[batch, cin, h, w], seed)).unwrap();
            let wt = Var::from_tensor(&random(&[cout, cin, k, k], seed + 1)).unwrap();
            let b = Var::from_tensor(&random(&[cout], seed + 2)).unwrap();
            let (hh, ww) = ((h + 2 * (k / 2) - k) / stride + 1, (w + 2 * (k / 2) - k) / stride + 1);
            let r = random(&[batch, cout, hh, ww], seed + 3);
            let rv = flat(&r);
            let loss = |x: &Tensor, wt: &Tensor, b: &Tensor| -> f64 {
                let y = flat(&conv2d(x, wt, Some(b), stride, k / 2).unwrap());
                y.iter().zip(&rv).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            for tile in [TILE_BYTES, 1] {
                let grads = our_grads(&x, &wt, &b, &r, stride, tile);
                for (arg, grad) in grads.iter().enumerate() {
                    let args = [x.as_tensor(), wt.as_tensor(), b.as_tensor()];
                    let differences = central_differences(&flat(args[arg]), eps, |v| {
                        let mut a = args.map(|t| t.clone());
                        a[arg] = tensor(v, args[arg].dims());
                        loss(&a[0], &a[1], &a[2])
                    });
                    assert_matches_differences(&flat(grad), &differences, 1e-3, &format!("k{k} s{stride} arg {arg}"));
                }
            }
        }
    }

    #[test]
    fn gradients_match_candle_autograd() {
        // Cout > Cin: input gradient by col2im; Cout < Cin and stride 1: by the flipped convolution.
        for (k, stride, (cin, cout)) in [3, 5, 7]
            .into_iter()
            .flat_map(|k| [1, 2].into_iter().flat_map(move |s| [(8, 16), (16, 8)].into_iter().map(move |c| (k, s, c))))
        {
            {
                let (batch, h, w) = (2, 23, 19);
                let seed = (k * 10 + stride + cin) as u64;
                let x = Var::from_tensor(&random(&[batch, cin, h, w], seed)).unwrap();
                let wt = Var::from_tensor(&random(&[cout, cin, k, k], seed + 1)).unwrap();
                let b = Var::from_tensor(&random(&[cout], seed + 2)).unwrap();
                let y = candle_conv(&x, &wt, &b, stride, k / 2);
                let r = random(y.dims(), seed + 3);
                let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let want = [&x, &wt, &b].map(|v| g.get(v).unwrap().clone());
                for tile in [TILE_BYTES, 4096, 1] {
                    let got = our_grads(&x, &wt, &b, &r, stride, tile);
                    for (arg, (got, want)) in got.iter().zip(&want).enumerate() {
                        let err = rel_err(got, want);
                        assert!(err < 1e-3, "k{k} s{stride} tile {tile} arg {arg}: {err}");
                    }
                }
            }
        }
    }

    #[test]
    fn narrow_kernels_match_candle_forward_and_backward() {
        // Rows beyond one band of the forward pass, columns beyond one block, and a tiny image.
        for (k, cout, (batch, cin, h, w)) in [3, 5, 7]
            .into_iter()
            .flat_map(|k| [1, 2].into_iter().flat_map(move |c| [(2, 5, 37, 70), (1, 2, 5, 4)].map(move |s| (k, c, s))))
        {
            let g = Geom::new((batch, cin, h, w), cout, k, 1, k / 2);
            assert!(narrow::applies(&g));
            let seed = (k * 10 + cout * 100 + h) as u64;
            let x = Var::from_tensor(&random(&[batch, cin, h, w], seed)).unwrap();
            let wt = Var::from_tensor(&random(&[cout, cin, k, k], seed + 1)).unwrap();
            let b = Var::from_tensor(&random(&[cout], seed + 2)).unwrap();
            let y = candle_conv(&x, &wt, &b, 1, k / 2);
            let r = random(y.dims(), seed + 3);
            let g = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let ours = conv2d(&x, &wt, Some(&b), 1, k / 2).unwrap();
            assert!(rel_err(&ours, &y) < 1e-4, "k{k} cout {cout} {h}x{w}: forward");
            let got = our_grads(&x, &wt, &b, &r, 1, TILE_BYTES);
            for (arg, v) in [&x, &wt, &b].into_iter().enumerate() {
                let err = rel_err(&got[arg], g.get(v).unwrap());
                assert!(err < 1e-4, "k{k} cout {cout} {h}x{w}: gradient of argument {arg}: {err}");
            }
        }
    }

    #[test]
    fn the_narrow_kernel_of_four_outputs_matches_candle_forward() {
        // The phases of a one-output 7x7 layer of an upsampled map: four outputs, 5x5.
        for (batch, cin, h, w) in [(2, 16, 37, 70), (1, 3, 6, 5)] {
            let g = Geom::new((batch, cin, h, w), 4, 5, 1, 2);
            assert!(narrow::applies_forward(&g) && !narrow::applies(&g));
            let x = random(&[batch, cin, h, w], 7);
            let wt = random(&[4, cin, 5, 5], 8);
            let b = random(&[4], 9);
            // Padded as a layer, and unpadded as the phases of `conv2d_of_upsampled`.
            for pad in [2, 0] {
                let want = candle_conv(&x, &wt, &b, 1, pad);
                let ours = conv2d(&x, &wt, Some(&b), 1, pad).unwrap();
                assert!(rel_err(&ours, &want) < 1e-4, "{h}x{w} padding {pad}");
            }
        }
    }

    #[test]
    fn input_gradient_is_skipped_for_constants() {
        let x = random(&[1, 2, 9, 9], 1);
        let w = Var::from_tensor(&random(&[3, 2, 3, 3], 2)).unwrap();
        let g = conv2d(&x, &w, None, 1, 1).unwrap().sum_all().unwrap().backward().unwrap();
        assert!(g.get(&x).is_none());
        assert!(g.get(&w).is_some());
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let run = |threads: usize, stride: usize, (cin, cout): (usize, usize)| -> Vec<Vec<u32>> {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let x = Var::from_tensor(&random(&[3, cin, 31, 29], 1)).unwrap();
                let w = Var::from_tensor(&random(&[cout, cin, 5, 5], 2)).unwrap();
                let b = Var::from_tensor(&random(&[cout], 3)).unwrap();
                // Small tiles: many tiles per image, several weight-gradient chunks.
                let y = conv2d_with_tile(&x, &w, Some(&b), stride, 2, false, 8192).unwrap();
                let r = random(y.dims(), 4);
                let g = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let bits = |t: &Tensor| flat(t).iter().map(|v| v.to_bits()).collect();
                vec![bits(&y), bits(g.get(&x).unwrap()), bits(g.get(&w).unwrap()), bits(g.get(&b).unwrap())]
            })
        };
        for stride in [1, 2] {
            for channels in [(6, 10), (10, 6), (7, 1), (5, 2)] {
                let one = run(1, stride, channels);
                for threads in [2, 3] {
                    assert!(one == run(threads, stride, channels), "s{stride} {channels:?}: 1 vs {threads} threads");
                }
            }
        }
    }
}
