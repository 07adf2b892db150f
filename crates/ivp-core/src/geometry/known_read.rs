//! The known-pixels-only bilinear read of ALGORITHMS.md §6.3 at test time, for any number of channels.
//!
//! Training reads with the `sample_bilinear` operator of `nn::ops` (every pixel of the crop, with
//! a backward pass); inference reads with this one, which skips pixels that are not known yet:
//! holes are black in the warped frame, and reading them would pull colours towards black.

use crate::geometry::image::Image;

/// The corners of a known-pixels-only bilinear read (ALGORITHMS.md §6.3) and their weights, found once so
/// that colour, depth and any other field can be read with the same weights.
#[derive(Clone, Copy, Debug)]
pub struct KnownRead {
    /// Pixel index and bilinear weight of each corner taken: top-left, top-right, bottom-left,
    /// bottom-right.
    corners: [(usize, f32); 4],
    count: usize,
    total_weight: f32,
}

impl KnownRead {
    /// The corners of the read at `(x, y)` that are inside the `width` x `height` frame, known and
    /// of positive weight; `None` when there is none or `(x, y)` is not finite.
    #[inline]
    pub fn at(width: usize, height: usize, known: &[bool], x: f32, y: f32) -> Option<Self> {
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (ax, ay) = (x - x0, y - y0);
        let weights = [
            (0.0, 0.0, (1.0 - ax) * (1.0 - ay)),
            (1.0, 0.0, ax * (1.0 - ay)),
            (0.0, 1.0, (1.0 - ax) * ay),
            (1.0, 1.0, ax * ay),
        ];
        let (w, h) = (width as f32, height as f32);
        let mut read = Self { corners: [(0, 0.0); 4], count: 0, total_weight: 0.0 };
        for (dx, dy, weight) in weights {
            let (cx, cy) = (x0 + dx, y0 + dy);
            // Range checks on floats first: the casts below must never see a huge value.
            if weight <= 0.0 || !(cx >= 0.0 && cx < w && cy >= 0.0 && cy < h) {
                continue;
            }
            let i = cy as usize * width + cx as usize;
            if !known[i] {
                continue;
            }
            read.corners[read.count] = (i, weight);
            read.count += 1;
            read.total_weight += weight;
        }
        (read.total_weight > 0.0).then_some(read)
    }

    /// The weighted mean of `image` over the corners.
    #[inline]
    pub fn read<const C: usize>(&self, image: &Image<C>) -> [f32; C] {
        let pixels = image.pixels();
        self.read_by(|i| pixels[i])
    }

    /// [`Self::read`] of the values `value(pixel index)`.
    #[inline]
    pub fn read_by<const C: usize>(&self, value: impl Fn(usize) -> [f32; C]) -> [f32; C] {
        let mut sum = [0f32; C];
        for &(i, weight) in &self.corners[..self.count] {
            for (s, c) in sum.iter_mut().zip(value(i)) {
                *s += weight * c;
            }
        }
        sum.map(|s| s / self.total_weight)
    }
}

/// ALGORITHMS.md §6.3 at test time, for an image of any number of channels (colour, depth maps, vector
/// fields): the bilinear read of `image` at `(x, y)` over the known in-frame corners, with
/// the weights renormalised over them. `None` when no corner remains or `(x, y)` is not finite.
pub fn sample_known<const C: usize>(image: &Image<C>, known: &[bool], x: f32, y: f32) -> Option<[f32; C]> {
    assert_eq!(known.len(), image.len(), "known mask does not match the image");
    KnownRead::at(image.width(), image.height(), known, x, y).map(|read| read.read(image))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_bilinear_read_renormalises_over_known_corners() {
        let image = Image::from_fn(4, 3, |u, v| [u as f32, v as f32, 1.0]);
        let all = vec![true; 12];
        let read = sample_known(&image, &all, 1.25, 0.5).unwrap();
        assert!((read[0] - 1.25).abs() < 1e-6 && (read[1] - 0.5).abs() < 1e-6 && (read[2] - 1.0).abs() < 1e-6);
        // Corner (2, 1) unknown: the rest, weights 0.375, 0.125, 0.375 of (1,0), (2,0), (1,1), renormalised.
        let mut known = all.clone();
        known[4 + 2] = false;
        let read = sample_known(&image, &known, 1.25, 0.5).unwrap();
        let total = 0.375 + 0.125 + 0.375;
        assert!((read[0] - (0.375 + 2.0 * 0.125 + 0.375) / total).abs() < 1e-6, "{read:?}");
        assert!((read[1] - 0.375 / total).abs() < 1e-6, "{read:?}");
        // Exactly on a pixel: only that pixel is a corner.
        assert_eq!(sample_known(&image, &all, 2.0, 1.0), Some([2.0, 1.0, 1.0]));
        assert_eq!(sample_known(&image, &known, 2.0, 1.0), None);
        // Half outside the frame: the in-frame corners only.
        assert_eq!(sample_known(&image, &all, -0.5, 0.0), Some([0.0, 0.0, 1.0]));
        for (x, y) in [(-1.0, 0.0), (4.0, 1.0), (1.0, 3.0), (f32::NAN, 1.0), (1e30, 1.0), (f32::NEG_INFINITY, 0.0)] {
            assert_eq!(sample_known(&image, &all, x, y), None, "({x}, {y})");
        }
        assert_eq!(sample_known(&image, &[false; 12], 1.5, 1.5), None);
    }

    #[test]
    fn colour_and_depth_reads_take_the_same_corners() {
        let (w, h) = (9, 6);
        let image = Image::from_fn(w, h, |u, v| [(u * 7 + v) as f32 * 0.013, (u + 3 * v) as f32 * 0.1, 0.3]);
        let depth = Image::from_fn(w, h, |u, v| [1.0 + (u * v) as f32 * 0.37]);
        let known: Vec<bool> = (0..w * h).map(|i| i % 3 != 1 && i % 7 != 2).collect();
        let mut state = 7u32;
        let mut random = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1 << 24) as f32
        };
        for _ in 0..2000 {
            let (x, y) = (random() * 11.0 - 1.0, random() * 8.0 - 1.0);
            let rgb = sample_known(&image, &known, x, y);
            // Depth reads with the same corners and weights: present exactly when colour is.
            let z = sample_known(&depth, &known, x, y);
            assert_eq!(z.is_some(), rgb.is_some());
        }
        // Exactly on a pixel: that pixel.
        assert_eq!(sample_known(&depth, &vec![true; w * h], 3.0, 2.0), Some(depth.get(3, 2)));
        assert_eq!(sample_known(&depth, &known, f32::NAN, 2.0), None);
    }
}
