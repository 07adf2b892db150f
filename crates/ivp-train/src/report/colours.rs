//! The colours of a report's images: error maps on one fixed scale for every method and frame,
//! holes marked on warped frames, and the legends of the error scale and of the vector colours.

use ivp_core::{Image, RgbImage, VectorField};

use crate::sheet::vectors_to_rgb;

/// The absolute error (8-bit levels, root of the mean over the channels of the squared error) at
/// which the error colour saturates. Fixed, so that colours compare across crops, frames and
/// reports.
pub const ERROR_SCALE_MAX: f32 = 64.0;

/// The colour of disocclusions in warped frames (magenta: no rendered content is that colour in
/// the test clips, and it stands out from the black of new regions).
pub const HOLE_COLOUR: [f32; 3] = [1.0, 0.0, 1.0];

/// Stops of the error colour map (black, purple, red, orange, pale yellow: "inferno"-like), from
/// no error to [`ERROR_SCALE_MAX`]; the lightness rises monotonically so that it reads in grey too.
const ERROR_STOPS: [[f32; 3]; 5] =
    [[0.0, 0.0, 0.02], [0.34, 0.06, 0.43], [0.73, 0.21, 0.33], [0.98, 0.55, 0.04], [0.99, 1.0, 0.64]];

/// The colour of a pixel's squared error (mean over channels, 0..255 scale): linear in the
/// absolute error up to [`ERROR_SCALE_MAX`], saturated beyond; NaN shows as grey.
pub fn error_colour(squared_error: f32) -> [f32; 3] {
    if squared_error.is_nan() {
        return [0.5; 3];
    }
    let t = (squared_error.max(0.0).sqrt() / ERROR_SCALE_MAX).min(1.0);
    let x = t * (ERROR_STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(ERROR_STOPS.len() - 2);
    let f = x - i as f32;
    let (a, b) = (ERROR_STOPS[i], ERROR_STOPS[i + 1]);
    [0, 1, 2].map(|c| a[c] + f * (b[c] - a[c]))
}

/// An error map: each disocclusion pixel in its error's colour, the other pixels the truth in
/// light grey (context only: the scores are of the disocclusions). The scale's colours are dark
/// to bright, so on a light grey ground even an exact (black) disocclusion stands out.
pub fn error_map(errors: &[f32], disocclusions: &[bool], truth: &RgbImage) -> RgbImage {
    let pixels = errors
        .iter()
        .zip(disocclusions)
        .zip(truth.pixels())
        .map(|((&e, &hole), t)| if hole { error_colour(e) } else { context_grey(*t) })
        .collect();
    Image::from_pixels(truth.width(), truth.height(), pixels)
}

/// A known pixel of an error map: its lightness squeezed into light greys.
fn context_grey([r, g, b]: [f32; 3]) -> [f32; 3] {
    let lightness = (0.2126 * r + 0.7152 * g + 0.0722 * b).clamp(0.0, 1.0);
    [0.6 + 0.3 * lightness; 3]
}

/// `image` with its disocclusions in [`HOLE_COLOUR`].
pub fn mark_holes(image: &RgbImage, disocclusions: &[bool]) -> RgbImage {
    let pixels =
        image.pixels().iter().zip(disocclusions).map(|(&p, &hole)| if hole { HOLE_COLOUR } else { p }).collect();
    Image::from_pixels(image.width(), image.height(), pixels)
}

/// The legend of the error scale: a bar from no error (left) to [`ERROR_SCALE_MAX`] (right).
pub fn error_legend(width: usize, height: usize) -> RgbImage {
    Image::from_fn(width, height, |u, _| {
        let absolute = ERROR_SCALE_MAX * u as f32 / (width.max(2) - 1) as f32;
        error_colour(absolute * absolute)
    })
}

/// The legend of the vector colours: a disc of radius `size / 2` whose every pixel shows the
/// vector from the centre to it, at full saturation on the rim (the longest vector of the crop).
pub fn vector_legend(size: usize) -> RgbImage {
    let r = size as f32 / 2.0;
    let field: VectorField = Image::from_fn(size, size, |u, v| {
        let (a, b) = (u as f32 + 0.5 - r, v as f32 + 0.5 - r);
        if a.hypot(b) <= r {
            [a, b]
        } else {
            [f32::NAN, f32::NAN]
        }
    });
    // Outside the disc: white rather than the black of non-finite vectors.
    let mut rgb = vectors_to_rgb(&field, Some(r));
    for (p, f) in rgb.pixels_mut().iter_mut().zip(field.pixels()) {
        if f[0].is_nan() {
            *p = [1.0; 3];
        }
    }
    rgb
}

/// The longest finite vector among the fields, so that several methods' vectors share one scale.
pub fn longest_vector<'a>(fields: impl Iterator<Item = &'a VectorField>) -> f32 {
    fields.flat_map(|f| f.pixels().iter()).map(|[a, b]| a.hypot(*b)).filter(|l| l.is_finite()).fold(0.0, f32::max)
}

/// `image` shrunk by the integer factor that brings its width to at most `max_width` (each block
/// its mean colour), unchanged when it already fits.
pub fn thumbnail(image: &RgbImage, max_width: usize) -> (RgbImage, usize) {
    let factor = image.width().div_ceil(max_width.max(1)).max(1);
    if factor == 1 {
        return (image.clone(), 1);
    }
    (ivp_core::geometry::shrink::shrink_image(image, factor), factor)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lightness(c: [f32; 3]) -> f32 {
        0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
    }

    #[test]
    fn the_error_scale_rises_in_lightness_and_saturates_at_its_maximum() {
        let steps: Vec<[f32; 3]> = (0..=80).map(|e| error_colour((e as f32).powi(2))).collect();
        assert_eq!(steps[0], ERROR_STOPS[0]);
        assert!(steps.windows(2).all(|w| lightness(w[1]) > lightness(w[0]) || w[1] == w[0]));
        assert!(lightness(steps[63]) < lightness(steps[64]), "still rising just below the maximum");
        assert_eq!(steps[64], ERROR_STOPS[4]);
        assert_eq!(steps[80], ERROR_STOPS[4], "saturated beyond the maximum");
        assert_eq!(error_colour(-1.0), ERROR_STOPS[0]);
        assert_eq!(error_colour(f32::NAN), [0.5; 3]);
        // The legend runs from the first stop to the last.
        let legend = error_legend(65, 2);
        assert_eq!((legend.get(0, 0), legend.get(64, 1)), (ERROR_STOPS[0], ERROR_STOPS[4]));
        assert_eq!(legend.get(32, 0), error_colour(32.0 * 32.0));
    }

    #[test]
    fn error_maps_colour_disocclusions_only() {
        let truth = RgbImage::filled(2, 1, [1.0; 3]);
        let map = error_map(&[4096.0, 4096.0], &[true, false], &truth);
        assert_eq!(map.get(0, 0), ERROR_STOPS[4]);
        assert!(map.get(1, 0).iter().all(|&c| (c - 0.9).abs() < 1e-6), "known pixels are light grey");
        assert_eq!(mark_holes(&truth, &[false, true]).get(1, 0), HOLE_COLOUR);
    }

    #[test]
    fn thumbnails_shrink_by_whole_factors_to_the_width_asked() {
        let wide = RgbImage::filled(1920, 1080, [0.5; 3]);
        let (small, factor) = thumbnail(&wide, 320);
        assert_eq!((small.width(), small.height(), factor), (320, 180, 6));
        let (same, factor) = thumbnail(&RgbImage::filled(320, 240, [0.5; 3]), 320);
        assert_eq!((same.width(), factor), (320, 1));
        let legend = vector_legend(16);
        assert_eq!(legend.get(0, 0), [1.0; 3], "outside the disc");
        assert_ne!(legend.get(15, 8), legend.get(0, 8), "opposite directions differ");
        let field = Image::from_pixels(2, 1, vec![[3.0, 4.0], [f32::NAN, 0.0]]);
        assert_eq!(longest_vector([&field].into_iter()), 5.0);
    }
}
