//! Labelled contact sheets: several images side by side with a caption above each, for looking at
//! samples, vectors and predictions.

use ivp_core::{DepthMap, HoleMask, Image, PixelClass, RgbImage, VectorField};
use ivp_data::samples::Sample;

const GLYPH: usize = 8;
/// Captions are drawn with the 8x8 bitmap font scaled by this factor.
const TEXT_SCALE: usize = 2;
const CAPTION_HEIGHT: usize = GLYPH * TEXT_SCALE + 8;
const GAP: usize = 6;

/// A grid of captioned tiles; every tile has the size of the first image added.
pub struct Sheet {
    columns: usize,
    tiles: Vec<(String, RgbImage)>,
}

impl Sheet {
    pub fn new(columns: usize) -> Self {
        Self { columns: columns.max(1), tiles: Vec::new() }
    }

    pub fn add(&mut self, caption: impl Into<String>, image: RgbImage) -> &mut Self {
        self.tiles.push((caption.into(), image));
        self
    }

    /// The sheet as one image: dark background, captions in white.
    pub fn render(&self) -> RgbImage {
        let (tw, th) = self.tiles.first().map_or((1, 1), |(_, img)| (img.width(), img.height()));
        let rows = self.tiles.len().div_ceil(self.columns).max(1);
        let cell_w = tw + GAP;
        let cell_h = th + CAPTION_HEIGHT + GAP;
        let mut sheet = Image::filled(self.columns * cell_w + GAP, rows * cell_h + GAP, [0.12, 0.12, 0.12]);
        for (i, (caption, img)) in self.tiles.iter().enumerate() {
            let (x0, y0) = (GAP + (i % self.columns) * cell_w, GAP + (i / self.columns) * cell_h);
            draw_text(&mut sheet, x0, y0 + 2, caption, tw);
            for v in 0..th.min(img.height()) {
                for u in 0..tw.min(img.width()) {
                    sheet.set(x0 + u, y0 + CAPTION_HEIGHT + v, img.get(u, v));
                }
            }
        }
        sheet
    }
}

/// A training sample as `ivp show-sample` draws it: the frames and warps it comes from, the
/// ground truth, its holes, its temporal prior and the warped depth, four to a row.
pub fn sample_sheet(sample: &Sample) -> Sheet {
    let size = sample.size();
    // 255 on disocclusions, 128 on new regions, 0 on known pixels.
    let holes = hole_mask(sample).to_gray8();
    let frames = &sample.origin.frames;
    let (n2, n, t) = (frames.before_last, frames.last, frames.target);
    let mut sheet = Sheet::new(4);
    sheet
        .add(format!("f{n2}->{n} warped"), sample.last_warped.clone())
        .add(format!("f{n} (last)"), sample.last.clone())
        .add(format!("f{n}->{t} warped"), sample.warped.clone())
        .add(format!("f{t} truth"), sample.truth.clone())
        .add("holes", gray_to_rgb(size, size, &holes))
        .add("prior", vectors_to_rgb(&sample.prior, None))
        .add(format!("depth {t}"), depth_to_rgb(&sample.warped_depth));
    sheet
}

/// Draws `text` at `(x, y)` in white, clipped to `max_width` pixels.
fn draw_text(image: &mut RgbImage, x: usize, y: usize, text: &str, max_width: usize) {
    draw_text_in(image, x, y, text, max_width, [1.0, 1.0, 1.0]);
}

/// Draws `text` at `(x, y)` in `colour`, clipped to `max_width` pixels; glyphs are 16 pixels wide.
pub(crate) fn draw_text_in(image: &mut RgbImage, x: usize, y: usize, text: &str, max_width: usize, colour: [f32; 3]) {
    let step = GLYPH * TEXT_SCALE;
    for (i, ch) in text.chars().take(max_width / step).enumerate() {
        let glyph = font8x8::legacy::BASIC_LEGACY.get(ch as usize).copied().unwrap_or([0; 8]);
        for (gy, bits) in glyph.iter().enumerate() {
            for gx in 0..GLYPH {
                if bits >> gx & 1 == 0 {
                    continue;
                }
                for dy in 0..TEXT_SCALE {
                    for dx in 0..TEXT_SCALE {
                        let (px, py) = (x + i * step + gx * TEXT_SCALE + dx, y + gy * TEXT_SCALE + dy);
                        if px < image.width() && py < image.height() {
                            image.set(px, py, colour);
                        }
                    }
                }
            }
        }
    }
}

/// Vectors as colours, like optical flow: hue is the direction, saturation the length relative to
/// `max_length` (the largest length in the field when `None`); zero vectors are white.
pub fn vectors_to_rgb(field: &VectorField, max_length: Option<f32>) -> RgbImage {
    let longest = max_length.unwrap_or_else(|| {
        field.pixels().iter().map(|[a, b]| a.hypot(*b)).filter(|l| l.is_finite()).fold(0.0, f32::max)
    });
    let scale = if longest > 0.0 { 1.0 / longest } else { 0.0 };
    Image::from_pixels(
        field.width(),
        field.height(),
        field
            .pixels()
            .iter()
            .map(|&[a, b]| {
                if !(a.is_finite() && b.is_finite()) {
                    return [0.0, 0.0, 0.0];
                }
                let hue = (b.atan2(a) / std::f32::consts::TAU).rem_euclid(1.0);
                hsv_to_rgb(hue, (a.hypot(b) * scale).min(1.0), 1.0)
            })
            .collect(),
    )
}

fn hsv_to_rgb(h: f32, s: f32, v: f32) -> [f32; 3] {
    let sector = h * 6.0;
    let f = sector - sector.floor();
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    match sector.floor() as i32 % 6 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

/// Depth as grey, near bright and far dark, scaled between the smallest and largest valid depth
/// in inverse depth (so that near detail shows); invalid or zero depth (holes) is shown red.
pub fn depth_to_rgb(depth: &DepthMap) -> RgbImage {
    let inverse: Vec<Option<f32>> =
        depth.as_flat().iter().map(|&z| (z.is_finite() && z > 0.0).then(|| 1.0 / z)).collect();
    let (lo, hi) = inverse.iter().flatten().fold((f32::INFINITY, 0f32), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    let range = if hi > lo { hi - lo } else { 1.0 };
    Image::from_pixels(
        depth.width(),
        depth.height(),
        inverse
            .iter()
            .map(|x| match x {
                Some(x) => {
                    let g = 0.1 + 0.9 * (x - lo) / range;
                    [g, g, g]
                }
                None => [0.8, 0.1, 0.1],
            })
            .collect(),
    )
}

/// A grey-level mask (e.g. the holes image: 255, 128, 0) as RGB.
pub fn gray_to_rgb(width: usize, height: usize, values: &[u8]) -> RgbImage {
    Image::from_pixels(width, height, values.iter().map(|&g| [g as f32 / 255.0; 3]).collect())
}

/// The holes of a sample's warp: disocclusions from its mask, new regions where the warp left no
/// depth and there is no disocclusion.
fn hole_mask(sample: &Sample) -> HoleMask {
    let classes = sample
        .mask
        .as_flat()
        .iter()
        .zip(sample.warped_depth.as_flat())
        .map(|(&m, &z)| {
            if m > 0.5 {
                PixelClass::Disocclusion
            } else if z > 0.0 {
                PixelClass::Known
            } else {
                PixelClass::NewRegion
            }
        })
        .collect();
    HoleMask::from_classes(sample.size(), sample.size(), classes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sheet_places_tiles_in_a_grid_with_captions() {
        let red = Image::filled(40, 30, [1.0, 0.0, 0.0]);
        let mut sheet = Sheet::new(2);
        sheet.add("A", red.clone()).add("B", red.clone()).add("C", red);
        let out = sheet.render();
        assert_eq!(out.width(), 2 * (40 + GAP) + GAP);
        assert_eq!(out.height(), 2 * (30 + CAPTION_HEIGHT + GAP) + GAP);
        // The first tile's pixels, below its caption.
        assert_eq!(out.get(GAP + 5, GAP + CAPTION_HEIGHT + 5), [1.0, 0.0, 0.0]);
        // Some caption pixel is white.
        let caption_white = (0..CAPTION_HEIGHT).any(|y| (0..40).any(|x| out.get(GAP + x, GAP + y) == [1.0; 3]));
        assert!(caption_white);
    }

    #[test]
    fn vector_colours_encode_direction_and_length() {
        let field = Image::from_pixels(3, 1, vec![[0.0, 0.0], [4.0, 0.0], [-4.0, 0.0]]);
        let rgb = vectors_to_rgb(&field, None);
        assert_eq!(rgb.get(0, 0), [1.0, 1.0, 1.0]);
        assert_ne!(rgb.get(1, 0), rgb.get(2, 0));
        let nan = Image::from_pixels(1, 1, vec![[f32::NAN, 1.0]]);
        assert_eq!(vectors_to_rgb(&nan, None).get(0, 0), [0.0; 3]);
    }

    #[test]
    fn depth_colours_put_near_brighter_and_holes_red() {
        let depth = Image::from_values(3, 1, vec![1.0, 10.0, 0.0]);
        let rgb = depth_to_rgb(&depth);
        assert!(rgb.get(0, 0)[0] > rgb.get(1, 0)[0]);
        assert_eq!(rgb.get(2, 0), [0.8, 0.1, 0.1]);
    }
}
