//! SceneNet RGB-D depth maps: u16 PNG of ray length in millimetres, 0 = no reading (ALGORITHMS.md §3).

use std::path::Path;

use image::DynamicImage;
use ivp_core::{DepthMap, Intrinsics};

use crate::error::{DataError, Result};
use crate::io::decode_image;

/// Frame numbers of a SceneNet trajectory step by 25 (0, 25, 50, ...).
pub const SCENENET_FRAME_STEP: u64 = 25;

/// Reads a SceneNet depth PNG as planar depth in metres; pixels without a reading become NaN.
pub fn read_scenenet_depth(path: impl AsRef<Path>, intrinsics: &Intrinsics) -> Result<DepthMap> {
    let path = path.as_ref();
    let DynamicImage::ImageLuma16(millimetres) = decode_image(path)? else {
        return Err(DataError::invalid(path, "SceneNet depth must be a 16-bit single-channel PNG"));
    };
    let (w, h) = (millimetres.width() as usize, millimetres.height() as usize);
    Ok(DepthMap::from_fn(w, h, |u, v| {
        [ray_mm_to_planar(millimetres.get_pixel(u as u32, v as u32).0[0], u, v, intrinsics)]
    }))
}

/// Ray length `mm` (millimetres) through pixel `(u, v)` to planar depth in metres:
/// `z = r / |K^-1 [u, v, 1]|`. A zero (no reading) is invalid depth: NaN.
pub fn ray_mm_to_planar(mm: u16, u: usize, v: usize, intrinsics: &Intrinsics) -> f32 {
    if mm == 0 {
        return f32::NAN;
    }
    let ray_metres = f64::from(mm) / 1000.0;
    (ray_metres / intrinsics.ray_length_per_depth(u as f64, v as f64)) as f32
}
