//! A convolution of a map upsampled bilinearly by 2, computed on the map itself, for inference:
//! the depth head's `c3(upsample(x))` (ALGORITHMS.md §6.1).
//!
//! Upsampling by 2 with half-pixel centres makes each output pixel `0.75 x[j] + 0.25 x[j -+ 1]`
//! of its input row and column, so a `k x k` convolution of the upsampled map is, for each of
//! its four output phases (row and column parity), a smaller convolution of the input: for
//! `k = 7`, `5 x 5`. The four phases together cost half the multiply-adds of the direct way, and
//! the upsampled map (the largest map of the depth head) is never built.
//!
//! At the map's border the two ways part: the direct convolution reads zeros beyond the
//! upsampled map, the phases read the upsampled map repeated (the input, padded by repeating its
//! edge, interpolates to its edge value there). The border pixels, within `k / 2` of the edge, are
//! corrected by subtracting what the taps beyond the edge added, so the result equals the direct
//! way up to the order of the sums.

use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex};

use candle_core::{bail, Device, Result, Tensor};
use rayon::prelude::*;

use crate::nn::ops::conv2d::add_product;
use crate::nn::ops::resize::bilinear_taps;
use crate::nn::ops::{conv2d, profile};

/// `conv2d(upsample_bilinear_to(x, 2 h, 2 w), weight, bias, stride 1, padding k / 2)`, then a
/// ReLU if `relu`, for `x` (B, Cin, h, w) and an odd square `weight` (Cout, Cin, k, k). No
/// gradient: for inference.
pub fn conv2d_of_upsampled(x: &Tensor, weight: &Tensor, bias: &Tensor, relu: bool) -> Result<Tensor> {
    let (b, cin, h, w) = x.dims4()?;
    let (cout, wcin, k, kw) = weight.dims4()?;
    if wcin != cin || k != kw || k % 2 == 0 || bias.dims() != [cout] {
        bail!("conv2d_of_upsampled: input {:?}, kernel {:?}, bias {:?}", x.dims(), weight.dims(), bias.dims());
    }
    if h == 0 || w == 0 {
        bail!("conv2d_of_upsampled: empty input {:?}", x.dims());
    }
    profile::timed("conv2d of upsampled", || {
        let weights: Vec<f32> = weight.flatten_all()?.to_vec1()?;
        let bias: Vec<f32> = bias.to_vec1()?;
        let prepared = Prepared::of(&weights, &bias, (cout, cin, k))?;
        let padded = pad_by_repeating(x, prepared.reach)?;
        // (B, 4 Cout, h, w): channel `phase * Cout + co`.
        let by_phase = conv2d(&padded, &prepared.phases, Some(&prepared.bias4), 1, 0)?;
        let by_phase: Vec<f32> = by_phase.flatten_all()?.to_vec1()?;
        let input: Vec<f32> = x.flatten_all()?.to_vec1()?;
        let (height, width) = (2 * h, 2 * w);
        // What the taps beyond the edge added at the border pixels, per image.
        let corrections: Vec<Corrections> = input
            .par_chunks_exact(cin * h * w)
            .map(|x| Corrections::new(&Edges::new(x, cin, h, w), &prepared.edges))
            .collect();
        // Each output row from its two phases, less the border's corrections, then the ReLU.
        let mut out = vec![0f32; b * cout * height * width];
        out.par_chunks_mut(width).enumerate().for_each(|(row, pixels)| {
            let (plane, oy) = (row / height, row % height);
            let (image, co) = (plane / cout, plane % cout);
            let phase_row = |px: usize| {
                let channel = ((oy % 2) * 2 + px) * cout + co;
                &by_phase[((image * 4 * cout + channel) * h + oy / 2) * w..][..w]
            };
            for ((pair, even), odd) in pixels.chunks_mut(2).zip(phase_row(0)).zip(phase_row(1)) {
                (pair[0], pair[1]) = (*even, *odd);
            }
            corrections[image].subtract_from_row(oy, co, pixels);
            if relu {
                pixels.iter_mut().for_each(|v| *v = v.max(0.0));
            }
        });
        Tensor::from_vec(out, (b, cout, height, width), &Device::Cpu)
    })
}

/// What a layer's weights give the phases: the phase kernels (4 Cout, Cin, s, s) with their bias,
/// and the kernels of the border's correction.
struct Prepared {
    phases: Tensor,
    bias4: Tensor,
    reach: usize,
    edges: EdgeKernels,
}

/// Layers prepared lately, by a hash of their weights' and bias' bits. Preparing costs about as
/// much as the phases of a small tile, and a 1080p frame calls the same two layers a dozen times
/// (every batch of tiles of every pass); weights that change (a network in training) miss.
static PREPARED: Mutex<Vec<(u64, Arc<Prepared>)>> = Mutex::new(Vec::new());

/// Layers [`PREPARED`] keeps: a few networks' depth heads.
const PREPARED_KEPT: usize = 8;

impl Prepared {
    fn of(weights: &[f32], bias: &[f32], (cout, cin, k): (usize, usize, usize)) -> Result<Arc<Self>> {
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        (cout, cin, k).hash(&mut hasher);
        weights.iter().chain(bias).for_each(|v| v.to_bits().hash(&mut hasher));
        let key = hasher.finish();
        let mut kept = PREPARED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, prepared)) = kept.iter().find(|(k, _)| *k == key) {
            return Ok(prepared.clone());
        }
        let (phases, reach) = phase_kernels(weights, cout, cin, k);
        let side = 2 * reach + 1;
        let bias4: Vec<f32> = bias.iter().copied().cycle().take(4 * cout).collect();
        let prepared = Arc::new(Self {
            phases: Tensor::from_vec(phases, (4 * cout, cin, side, side), &Device::Cpu)?,
            bias4: Tensor::from_vec(bias4, 4 * cout, &Device::Cpu)?,
            reach,
            edges: EdgeKernels::new(weights, cout, cin, k),
        });
        if kept.len() == PREPARED_KEPT {
            kept.remove(0);
        }
        kept.push((key, prepared.clone()));
        Ok(prepared)
    }
}

/// The four phase kernels of `weights` (Cout, Cin, k, k), phase `py * 2 + px` first, then output
/// channel: `(4 Cout, Cin, 2 reach + 1, 2 reach + 1)` row-major, and `reach`.
fn phase_kernels(weights: &[f32], cout: usize, cin: usize, k: usize) -> (Vec<f32>, usize) {
    let r = k / 2;
    // Output pixel 2 j + p reads upsampled pixel 2 j + p + t - r (t in 0..k), which mixes input
    // pixels j - 2 .. j + 2 (for k = 7): within `reach` of j.
    let reach = (r + 2) / 2;
    let side = 2 * reach + 1;
    // mix[p][t][d]: weight of input pixel j + d - reach in upsampled pixel 2 j + p + t - r, read
    // from the upsampling's own taps at an input pixel j far enough from both edges.
    let n = 2 * reach + 4;
    let j = reach + 1;
    let taps = bilinear_taps(n, 2 * n);
    let mix: Vec<Vec<Vec<f32>>> = (0..2)
        .map(|p| {
            (0..k)
                .map(|t| {
                    let (i0, i1, w0, w1) = taps[2 * j + p + t - r];
                    let mut row = vec![0f32; side];
                    row[i0 + reach - j] += w0;
                    row[i1 + reach - j] += w1;
                    row
                })
                .collect()
        })
        .collect();
    let mut phases = vec![0f32; 4 * cout * cin * side * side];
    let mut along_x = vec![0f32; k * side];
    for (co, ci) in (0..cout).flat_map(|co| (0..cin).map(move |ci| (co, ci))) {
        let kernel = &weights[(co * cin + ci) * k * k..][..k * k];
        for px in 0..2 {
            // Mixed along the columns first, then along the rows: the kernel is (ty, tx).
            along_x.fill(0.0);
            for (ty, row) in kernel.chunks_exact(k).enumerate() {
                for (kv, mix_x) in row.iter().zip(&mix[px]) {
                    along_x[ty * side..][..side].iter_mut().zip(mix_x).for_each(|(a, m)| *a += kv * m);
                }
            }
            for (py, mix_py) in mix.iter().enumerate() {
                let phase = py * 2 + px;
                let out = &mut phases[((phase * cout + co) * cin + ci) * side * side..][..side * side];
                for (row, mix_y) in along_x.chunks_exact(side).zip(mix_py) {
                    for (dy, &my) in mix_y.iter().enumerate().filter(|(_, &m)| m != 0.0) {
                        out[dy * side..][..side].iter_mut().zip(row).for_each(|(o, a)| *o += my * a);
                    }
                }
            }
        }
    }
    (phases, reach)
}

/// `x` (B, C, h, w) padded by `pad` pixels on every side, each copying the nearest edge pixel.
fn pad_by_repeating(x: &Tensor, pad: usize) -> Result<Tensor> {
    let (b, c, h, w) = x.dims4()?;
    let values: Vec<f32> = x.flatten_all()?.to_vec1()?;
    let (ph, pw) = (h + 2 * pad, w + 2 * pad);
    let mut out = vec![0f32; b * c * ph * pw];
    out.par_chunks_mut(ph * pw).zip(values.par_chunks(h * w)).for_each(|(out, plane)| {
        for (y, row) in out.chunks_mut(pw).enumerate() {
            let source = &plane[(y.saturating_sub(pad)).min(h - 1) * w..][..w];
            for (x, v) in row.iter_mut().enumerate() {
                *v = source[x.saturating_sub(pad).min(w - 1)];
            }
        }
    });
    Tensor::from_vec(out, (b, c, ph, pw), &Device::Cpu)
}

/// The upsampled map's outermost rows and columns, each pixel's channels together: all that the
/// taps beyond its edge read when it is taken as repeated there.
struct Edges {
    height: usize,
    lines: Sides<Vec<f32>>,
}

/// One of a thing for each side of a map.
struct Sides<T> {
    top: T,
    bottom: T,
    left: T,
    right: T,
}

impl Edges {
    /// Of `input` (Cin, h, w) upsampled by 2.
    fn new(input: &[f32], cin: usize, h: usize, w: usize) -> Self {
        let (height, width) = (2 * h, 2 * w);
        let (rows, columns) = (bilinear_taps(h, height), bilinear_taps(w, width));
        // Pixel (y, x) of channel c, weighed as `upsample_bilinear_to` weighs it.
        let upsampled = |c: usize, y: usize, x: usize| {
            let ((y0, y1, ly0, ly1), (x0, x1, lx0, lx1)) = (rows[y], columns[x]);
            let at = |y: usize, x: usize| input[(c * h + y) * w + x];
            ly0 * (lx0 * at(y0, x0) + lx1 * at(y0, x1)) + ly1 * (lx0 * at(y1, x0) + lx1 * at(y1, x1))
        };
        let line = |pixels: Vec<(usize, usize)>| -> Vec<f32> {
            pixels.into_iter().flat_map(|(y, x)| (0..cin).map(move |c| upsampled(c, y, x))).collect()
        };
        Self {
            height,
            lines: Sides {
                top: line((0..width).map(|x| (0, x)).collect()),
                bottom: line((0..width).map(|x| (height - 1, x)).collect()),
                left: line((0..height).map(|y| (y, 0)).collect()),
                right: line((0..height).map(|y| (y, width - 1)).collect()),
            },
        }
    }
}

/// Sums of the kernel's taps over the rows (or columns) that fall beyond the edge, for every
/// number of them: the taps beyond one edge all read that edge's pixel, so they act as one.
/// Each is laid out (k, Cin, Cout): a tap's weights for every output channel together.
///
/// `[n - 1]` of a side: the `n` rows (columns) of taps nearest that side summed, as a row
/// (column) of `k` taps along the edge.
struct EdgeKernels {
    k: usize,
    cin: usize,
    cout: usize,
    sides: Sides<Vec<Vec<f32>>>,
}

impl EdgeKernels {
    fn new(weights: &[f32], cout: usize, cin: usize, k: usize) -> Self {
        let r = k / 2;
        let at = |co: usize, ci: usize, ty: usize, tx: usize| weights[((co * cin + ci) * k + ty) * k + tx];
        // Taps `t` of the summed kernel: rows (or columns) `lines` summed at position `t` across.
        let summed = |lines: std::ops::Range<usize>, along_rows: bool| -> Vec<f32> {
            let mut out = vec![0f32; k * cin * cout];
            for t in 0..k {
                for ci in 0..cin {
                    for co in 0..cout {
                        out[(t * cin + ci) * cout + co] =
                            lines.clone().map(|l| if along_rows { at(co, ci, l, t) } else { at(co, ci, t, l) }).sum();
                    }
                }
            }
            out
        };
        Self {
            k,
            cin,
            cout,
            sides: Sides {
                top: (1..=r).map(|n| summed(0..n, true)).collect(),
                bottom: (1..=r).map(|n| summed(k - n..k, true)).collect(),
                left: (1..=r).map(|n| summed(0..n, false)).collect(),
                right: (1..=r).map(|n| summed(k - n..k, false)).collect(),
            },
        }
    }
}

/// What the taps beyond the upsampled map's edge add to its border pixels when the map is taken
/// as repeated past its edge, for every output channel: `top[n - 1]` (`width x Cout`) for the row
/// with `n` rows of taps beyond the top edge (row `r - n`), `left[n - 1]` (`height x Cout`) for
/// the column with `n` columns of taps beyond the left edge, and so on.
///
/// Rows of taps beyond the top or bottom edge take every column (the edge row repeated along it,
/// so its ends repeat too); columns of taps beyond the left or right edge take only the rows
/// inside the map (the rows beyond are the top's and bottom's), which is the edge column padded
/// with zeros. Either way a border line is a 1-D convolution of an edge line with a summed kernel
/// ([`EdgeKernels`]): one matrix product per line, whose left operand is the padded edge line
/// read with overlapping rows.
struct Corrections {
    cout: usize,
    height: usize,
    sides: Sides<Vec<Vec<f32>>>,
}

impl Corrections {
    fn new(edges: &Edges, kernels: &EdgeKernels) -> Self {
        let (k, cin, cout) = (kernels.k, kernels.cin, kernels.cout);
        let r = k / 2;
        let along = |line: &[f32], repeat: bool, kernels: &[Vec<f32>]| -> Vec<Vec<f32>> {
            let n = line.len() / cin;
            let mut padded = vec![0f32; (n + 2 * r) * cin];
            padded[r * cin..][..n * cin].copy_from_slice(line);
            if repeat {
                for i in 0..r {
                    padded.copy_within(r * cin..(r + 1) * cin, i * cin);
                    padded.copy_within((r + n - 1) * cin..(r + n) * cin, (r + n + i) * cin);
                }
            }
            kernels
                .iter()
                .map(|kernel| {
                    let mut out = vec![0f32; n * cout];
                    add_product((n, cout, k * cin), (&padded, cin), (kernel, cout), (&mut out, cout));
                    out
                })
                .collect()
        };
        Self {
            cout,
            height: edges.height,
            sides: Sides {
                top: along(&edges.lines.top, true, &kernels.sides.top),
                bottom: along(&edges.lines.bottom, true, &kernels.sides.bottom),
                left: along(&edges.lines.left, false, &kernels.sides.left),
                right: along(&edges.lines.right, false, &kernels.sides.right),
            },
        }
    }

    /// Subtracts the corrections of channel `co` from row `oy` of the output map (`pixels`).
    fn subtract_from_row(&self, oy: usize, co: usize, pixels: &mut [f32]) {
        let (height, width, r, c) = (self.height, pixels.len(), self.sides.top.len(), self.cout);
        // Rows of taps beyond the top and the bottom edge, at every pixel of the row.
        let (above, below) = (r.saturating_sub(oy), (oy + r + 1).saturating_sub(height));
        for (n, lines) in [(above, &self.sides.top), (below, &self.sides.bottom)] {
            if n > 0 {
                let line = &lines[n - 1];
                pixels.iter_mut().enumerate().for_each(|(ox, v)| *v -= line[ox * c + co]);
            }
        }
        // Columns of taps beyond the left and the right edge, at the first and last pixels.
        for ox in (0..r.min(width)).chain(width.saturating_sub(r).max(r)..width) {
            let (before, after) = (r.saturating_sub(ox), (ox + r + 1).saturating_sub(width));
            for (n, lines) in [(before, &self.sides.left), (after, &self.sides.right)] {
                if n > 0 {
                    pixels[ox] -= lines[n - 1][oy * c + co];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::{flat, random};
    use crate::nn::ops::{conv2d_relu, upsample_bilinear_to};

    #[test]
    fn equals_upsampling_then_convolving_at_every_pixel() {
        for (b, cin, cout, h, w, k) in [
            (2, 3, 4, 5, 7, 7),
            (1, 2, 1, 1, 1, 7),
            (1, 1, 2, 2, 3, 7),
            (1, 2, 2, 9, 1, 7),
            (1, 2, 2, 1, 9, 7),
            (1, 4, 3, 9, 4, 3),
            (2, 2, 2, 6, 6, 5),
            (1, 3, 2, 8, 11, 1),
        ] {
            let x = random(&[b, cin, h, w], 11);
            let weight = random(&[cout, cin, k, k], 12);
            let bias = random(&[cout], 13);
            let up = upsample_bilinear_to(&x, 2 * h, 2 * w).unwrap();
            for relu in [false, true] {
                let want = match relu {
                    true => conv2d_relu(&up, &weight, Some(&bias), 1, k / 2).unwrap(),
                    false => conv2d(&up, &weight, Some(&bias), 1, k / 2).unwrap(),
                };
                let got = conv2d_of_upsampled(&x, &weight, &bias, relu).unwrap();
                assert_eq!(got.dims(), want.dims());
                let worst = flat(&got).iter().zip(flat(&want)).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
                assert!(worst < 1e-5, "B{b} {cin}->{cout} {h}x{w} k{k} relu {relu}: largest difference {worst}");
            }
        }
    }

    #[test]
    fn refuses_even_kernels_and_empty_maps() {
        let bias = random(&[2], 1);
        assert!(conv2d_of_upsampled(&random(&[1, 1, 4, 4], 1), &random(&[2, 1, 4, 4], 2), &bias, false).is_err());
        assert!(conv2d_of_upsampled(&random(&[1, 2, 4, 4], 1), &random(&[2, 1, 3, 3], 2), &bias, false).is_err());
        let empty = Tensor::zeros((1, 1, 0, 4), candle_core::DType::F32, &Device::Cpu).unwrap();
        assert!(conv2d_of_upsampled(&empty, &random(&[2, 1, 3, 3], 2), &bias, false).is_err());
    }
}
