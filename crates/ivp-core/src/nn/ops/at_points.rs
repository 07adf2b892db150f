//! The U-Net's decoder step evaluated at chosen output pixels only, for inference.
//!
//! At test time the network's vectors are read only at the pixels to predict, a few percent of a
//! tile. A decoder level's output at a pixel depends on a 3x3 neighbourhood of its input, which
//! is the level below upsampled (nearest) and the encoder's skip: so a few pixels at each level
//! need only a few pixels of the level below ([`pixels_read`]), and the decoder costs almost
//! nothing ([`decoder_step_at`]). The encoder still runs over its whole input: its maps feed the
//! deeper levels everywhere.

use candle_core::{bail, DType, Device, Result, Storage, Tensor};

use rayon::prelude::*;

use std::ops::Range;

use crate::nn::ops::conv2d::add_product;
use crate::nn::ops::{contiguous_values, profile};

/// One pixel of a batch of maps: image, row, column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct BatchPixel {
    pub image: usize,
    pub y: usize,
    pub x: usize,
}

/// The pixels of a `(batch, height, width)` map upsampled (nearest, x2, cropped to `fine`) that
/// a 3x3 convolution with zero padding reads to compute `points` of the `fine` map: each point's
/// in-bounds neighbours, halved. In row-major order, each once.
pub fn pixels_read(points: &[BatchPixel], fine: (usize, usize), coarse: (usize, usize, usize)) -> Vec<BatchPixel> {
    let (height, width) = fine;
    let (batch, h, w) = coarse;
    let mut read = vec![false; batch * h * w];
    for p in points {
        for y in p.y.saturating_sub(1)..(p.y + 2).min(height) {
            for x in p.x.saturating_sub(1)..(p.x + 2).min(width) {
                read[(p.image * h + y / 2) * w + x / 2] = true;
            }
        }
    }
    read.iter()
        .enumerate()
        .filter(|(_, &r)| r)
        .map(|(i, _)| BatchPixel { image: i / (h * w), y: i / w % h, x: i % w })
        .collect()
}

/// `conv3x3(cat([upsample_nearest2x(coarse), skip]))` plus `bias` (then a ReLU if `relu`), with
/// zero padding, at `points` of the skip's size only: one row of `Cout` values per point,
/// (N, Cout).
///
/// `coarse` is (B, Cc, h, w), `skip` (B, Cs, H, W) with H <= 2h and W <= 2w, `weight`
/// (Cout, Cc + Cs, 3, 3). Only the pixels of `coarse` that [`pixels_read`] names are read, so a
/// coarse map computed at those pixels only (zeros elsewhere) gives the same result as a whole
/// one. Equals [`crate::nn::ops::upsample_concat`] then [`crate::nn::ops::conv2d`] at those
/// pixels, up to the order of the sums.
pub fn decoder_step_at(
    coarse: &Tensor,
    skip: &Tensor,
    weight: &Tensor,
    bias: &Tensor,
    relu: bool,
    points: &[BatchPixel],
) -> Result<Tensor> {
    let (b, cc, h, w) = coarse.dims4()?;
    let (bs, cs, height, width) = skip.dims4()?;
    let (cout, cin, kh, kw) = weight.dims4()?;
    if bs != b || height > 2 * h || width > 2 * w || cin != cc + cs || (kh, kw) != (3, 3) || bias.dims() != [cout] {
        bail!(
            "decoder_step_at: coarse {:?}, skip {:?}, weight {:?} and bias {:?} do not fit",
            coarse.dims(),
            skip.dims(),
            weight.dims(),
            bias.dims()
        );
    }
    if let Some(p) = points.iter().find(|p| p.image >= b || p.y >= height || p.x >= width) {
        bail!("decoder_step_at: point {p:?} outside the {b}x{height}x{width} maps");
    }
    let taps = cin * 9;
    if points.is_empty() {
        return Tensor::zeros((0, cout), DType::F32, &Device::Cpu);
    }
    let values = profile::timed("decoder at points", || -> Result<Vec<f32>> {
        let tensors = [coarse, skip, weight, bias].map(|t| t.contiguous());
        let [coarse, skip, weight, bias] = tensors;
        let (coarse, skip, weight, bias) = (coarse?, skip?, weight?, bias?);
        let guards = [&coarse, &skip, &weight, &bias].map(|t| t.storage_and_layout());
        let mut slices = Vec::with_capacity(4);
        for (storage, layout) in &guards {
            let Storage::Cpu(storage) = &**storage else { bail!("decoder_step_at: CPU tensors expected") };
            slices.push(contiguous_values(storage, layout, "decoder_step_at")?);
        }
        let [coarse, skip, weight, bias] = slices[..] else { unreachable!("four tensors") };
        let n = points.len();
        // Where each tap of each point reads within one channel's plane (None: in the padding),
        // in the upsampled coarse level and in the skip.
        let offsets = |upsampled: bool| -> Vec<Option<usize>> {
            let (plane, row) = if upsampled { (cc * h * w, w) } else { (cs * height * width, width) };
            (0..9)
                .flat_map(|tap| points.iter().map(move |p| (tap, p)))
                .map(|(tap, p)| {
                    let y = (p.y + tap / 3).checked_sub(1).filter(|&y| y < height)?;
                    let x = (p.x + tap % 3).checked_sub(1).filter(|&x| x < width)?;
                    Some(match upsampled {
                        true => p.image * plane + y / 2 * row + x / 2,
                        false => p.image * plane + y * row + x,
                    })
                })
                .collect()
        };
        let (from_coarse, from_skip) = (offsets(true), offsets(false));
        // im2col of the points: row (channel, tap) holds what each point reads through that tap.
        let mut cols = vec![0f32; taps * n];
        cols.par_chunks_mut(9 * n).enumerate().for_each(|(channel, rows)| {
            let (plane, offsets) = match channel < cc {
                true => (&coarse[channel * h * w..], &from_coarse),
                false => (&skip[(channel - cc) * height * width..], &from_skip),
            };
            for (v, offset) in rows.iter_mut().zip(offsets) {
                if let Some(o) = offset {
                    *v = plane[*o];
                }
            }
        });
        // The weights (Cout x taps) times the columns (taps x N), in blocks of output channels
        // and of points, in parallel; the blocks are fixed by the shapes, so the sums do not
        // depend on the number of threads.
        let blocks: Vec<(Range<usize>, Range<usize>)> = (0..cout)
            .step_by(CHANNELS_PER_BLOCK)
            .flat_map(|c| (0..n).step_by(POINTS_PER_BLOCK).map(move |p| (c, p)))
            .map(|(c, p)| (c..(c + CHANNELS_PER_BLOCK).min(cout), p..(p + POINTS_PER_BLOCK).min(n)))
            .collect();
        let products: Vec<Vec<f32>> = blocks
            .par_iter()
            .map(|(channels, pixels)| {
                let mut product: Vec<f32> =
                    channels.clone().flat_map(|c| std::iter::repeat_n(bias[c], pixels.len())).collect();
                let weights = &weight[channels.start * taps..channels.end * taps];
                add_product(
                    (channels.len(), pixels.len(), taps),
                    (weights, taps),
                    (&cols[pixels.start..], n),
                    (&mut product, pixels.len()),
                );
                product
            })
            .collect();
        let mut out = vec![0f32; n * cout];
        for ((channels, pixels), product) in blocks.iter().zip(&products) {
            for (c, row) in channels.clone().zip(product.chunks_exact(pixels.len())) {
                for (i, v) in pixels.clone().zip(row) {
                    out[i * cout + c] = if relu { v.max(0.0) } else { *v };
                }
            }
        }
        Ok(out)
    })?;
    Tensor::from_vec(values, (points.len(), cout), &Device::Cpu)
}

/// Output channels and points of one product block of [`decoder_step_at`] (a fixed size, so that
/// results do not depend on the number of threads): large enough for gemm's kernels.
const CHANNELS_PER_BLOCK: usize = 64;
const POINTS_PER_BLOCK: usize = 512;

/// The map of shape (B, C, H, W) that holds `values` (N, C) at `points` and zeros elsewhere.
pub fn scatter(values: &Tensor, points: &[BatchPixel], (b, c, h, w): (usize, usize, usize, usize)) -> Result<Tensor> {
    let (n, cv) = values.dims2()?;
    if n != points.len() || cv != c {
        bail!("scatter: {:?} values for {} points of {c} channels", values.dims(), points.len());
    }
    let values: Vec<f32> = values.to_dtype(DType::F32)?.flatten_all()?.to_vec1()?;
    let mut map = vec![0f32; b * c * h * w];
    for (p, row) in points.iter().zip(values.chunks_exact(c)) {
        for (ch, v) in row.iter().enumerate() {
            map[((p.image * c + ch) * h + p.y) * w + p.x] = *v;
        }
    }
    Tensor::from_vec(map, (b, c, h, w), &Device::Cpu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::test_util::{flat, random};
    use crate::nn::ops::{conv2d, conv2d_relu, upsample_concat};

    /// Points spread over both images, the borders and the corners of an odd-sized map.
    fn points(b: usize, height: usize, width: usize) -> Vec<BatchPixel> {
        let mut points: Vec<BatchPixel> = (0..b)
            .flat_map(|image| (0..height).flat_map(move |y| (0..width).map(move |x| BatchPixel { image, y, x })))
            .filter(|p| (p.y * 7 + p.x * 3 + p.image) % 5 == 0 || p.y == 0 || p.x == width - 1)
            .collect();
        points.sort();
        points
    }

    #[test]
    fn the_decoder_step_at_points_equals_the_dense_step_there() {
        // The last case has more points and channels than one product block holds.
        for (b, cc, cs, cout, h, w, height, width) in [
            (2, 5, 3, 4, 6, 9, 12, 18),
            (2, 5, 3, 4, 6, 9, 11, 17),
            (2, 5, 3, 4, 1, 1, 2, 1),
            (2, 6, 4, CHANNELS_PER_BLOCK + 6, 20, 21, 40, 41),
        ] {
            let coarse = random(&[b, cc, h, w], 1);
            let skip = random(&[b, cs, height, width], 2);
            let weight = random(&[cout, cc + cs, 3, 3], 3);
            let bias = random(&[cout], 4);
            let input = upsample_concat(&coarse, &skip).unwrap();
            for relu in [false, true] {
                let dense = match relu {
                    true => conv2d_relu(&input, &weight, Some(&bias), 1, 1).unwrap(),
                    false => conv2d(&input, &weight, Some(&bias), 1, 1).unwrap(),
                };
                let dense = flat(&dense);
                let pts = points(b, height, width);
                assert!(height < 40 || pts.len() > POINTS_PER_BLOCK, "{} points", pts.len());
                let at = flat(&decoder_step_at(&coarse, &skip, &weight, &bias, relu, &pts).unwrap());
                for (i, p) in pts.iter().enumerate() {
                    for c in 0..cout {
                        let want = dense[((p.image * cout + c) * height + p.y) * width + p.x];
                        let got = at[i * cout + c];
                        assert!(
                            (want - got).abs() < 1e-5,
                            "{h}x{w} -> {height}x{width}, {p:?} channel {c}: {got} vs {want}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn a_coarse_map_known_only_where_it_is_read_gives_the_same_values() {
        let (b, cc, cs, cout, h, w, height, width) = (2, 3, 2, 2, 7, 5, 13, 10);
        let coarse = random(&[b, cc, h, w], 5);
        let skip = random(&[b, cs, height, width], 6);
        let (weight, bias) = (random(&[cout, cc + cs, 3, 3], 7), random(&[cout], 8));
        let pts: Vec<BatchPixel> = vec![
            BatchPixel { image: 0, y: 0, x: 0 },
            BatchPixel { image: 1, y: 6, x: 9 },
            BatchPixel { image: 1, y: 12, x: 3 },
        ];
        let read = pixels_read(&pts, (height, width), (b, h, w));
        // Keep the coarse values at the pixels read, zero the rest.
        let values = flat(&coarse);
        let kept: Vec<f32> = read
            .iter()
            .flat_map(|p| (0..cc).map(move |c| ((p.image * cc + c) * h + p.y) * w + p.x))
            .map(|i| values[i])
            .collect();
        let kept = Tensor::from_vec(kept, (read.len(), cc), &Device::Cpu).unwrap();
        // (N, C) rows at the points: scatter wants the values point-major.
        let sparse = scatter(&kept, &read, (b, cc, h, w)).unwrap();
        assert!(flat(&sparse).iter().filter(|&&v| v == 0.0).count() > b * cc * h * w / 2, "most of the map is dropped");
        let whole = flat(&decoder_step_at(&coarse, &skip, &weight, &bias, true, &pts).unwrap());
        let from_sparse = flat(&decoder_step_at(&sparse, &skip, &weight, &bias, true, &pts).unwrap());
        assert_eq!(whole, from_sparse);
        // The pixels read, row-major and once each: the corner's 2x2 neighbours halve to one
        // pixel; (6, 9) reads rows 5-7 and columns 8-9 (the last); (12, 3) rows 11-12, columns 2-4.
        let px = |image, y, x| BatchPixel { image, y, x };
        let want = [px(0, 0, 0), px(1, 2, 4), px(1, 3, 4), px(1, 5, 1), px(1, 5, 2), px(1, 6, 1), px(1, 6, 2)];
        assert_eq!(read, want);
    }

    #[test]
    fn mismatched_shapes_and_points_outside_are_errors() {
        let coarse = random(&[1, 2, 3, 3], 1);
        let skip = random(&[1, 1, 6, 6], 2);
        let (weight, bias) = (random(&[2, 3, 3, 3], 3), random(&[2], 4));
        let outside = [BatchPixel { image: 0, y: 6, x: 0 }];
        assert!(decoder_step_at(&coarse, &skip, &weight, &bias, false, &outside).is_err());
        let wrong = random(&[2, 4, 3, 3], 3);
        assert!(decoder_step_at(&coarse, &skip, &wrong, &bias, false, &[]).is_err());
        let too_big = random(&[1, 1, 7, 6], 2);
        assert!(decoder_step_at(&coarse, &too_big, &weight, &bias, false, &[]).is_err());
    }
}
