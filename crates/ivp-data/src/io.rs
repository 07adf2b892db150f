//! Image (PNG/JPEG) and depth (EXR) files. Every write is atomic: the bytes go to a temporary file in
//! the destination's folder, which is then renamed over the destination, so that a reader (or a
//! crashed writer) never leaves a half-written frame behind.

use std::fs;
use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use exr::prelude as ex;
use exr::prelude::traits::*; // the builder methods of `exr` live in traits
use image::{DynamicImage, ImageEncoder, ImageReader};
use ivp_core::geometry::image::to_u8;
use ivp_core::{DepthMap, RgbImage};

use crate::error::{DataError, Result};

/// Depth channel names in order of preference when an EXR has more than one channel (ALGORITHMS.md §3).
/// IISc-VEED stores depth in all of R, G, B and its reference code reads `B`.
pub const DEPTH_CHANNELS: [&str; 4] = ["Z", "depth.Z", "Y", "B"];

/// The channel written by [`write_depth_exr`] (Blender's name for a single grey channel).
pub const WRITTEN_DEPTH_CHANNEL: &str = "Y";

/// Reads an 8- or 16-bit PNG (RGB, RGBA, grey, grey+alpha) or a JPEG as RGB in `[0, 1]`.
/// Alpha is dropped; grey is replicated to the three channels.
pub fn read_rgb(path: impl AsRef<Path>) -> Result<RgbImage> {
    let path = path.as_ref();
    let decoded = decode_image(path)?;
    let (w, h) = (decoded.width() as usize, decoded.height() as usize);
    let pixels: Vec<[f32; 3]> = match decoded {
        // 8-bit: exactly `v / 255`, the same grid as `Image::quantized_to_8bit`.
        DynamicImage::ImageLuma8(_)
        | DynamicImage::ImageLumaA8(_)
        | DynamicImage::ImageRgb8(_)
        | DynamicImage::ImageRgba8(_) => decoded.to_rgb8().pixels().map(|p| p.0.map(|c| c as f32 / 255.0)).collect(),
        DynamicImage::ImageLuma16(_)
        | DynamicImage::ImageLumaA16(_)
        | DynamicImage::ImageRgb16(_)
        | DynamicImage::ImageRgba16(_) => {
            decoded.to_rgb16().pixels().map(|p| p.0.map(|c| c as f32 / 65535.0)).collect()
        }
        _ => decoded.to_rgb32f().pixels().map(|p| p.0).collect(),
    };
    Ok(RgbImage::from_pixels(w, h, pixels))
}

/// Decodes any image the `image` crate knows, guessing the format from the content (not the name).
pub(crate) fn decode_image(path: &Path) -> Result<DynamicImage> {
    let reader = ImageReader::open(path).map_err(|e| DataError::io(path, "cannot open image", e))?;
    let reader = reader.with_guessed_format().map_err(|e| DataError::io(path, "cannot read image", e))?;
    reader.decode().map_err(|e| DataError::image(path, "cannot decode image", e))
}

/// Width and height of a PNG/JPEG from its header only (no pixel decoding).
pub(crate) fn image_size(path: &Path) -> Result<(usize, usize)> {
    let reader = ImageReader::open(path).map_err(|e| DataError::io(path, "cannot open image", e))?;
    let reader = reader.with_guessed_format().map_err(|e| DataError::io(path, "cannot read image", e))?;
    let (w, h) = reader.into_dimensions().map_err(|e| DataError::image(path, "cannot read image header", e))?;
    Ok((w as usize, h as usize))
}

/// Writes an 8-bit RGB PNG (values rounded with [`to_u8`]).
pub fn write_rgb_png(path: impl AsRef<Path>, image: &RgbImage) -> Result<()> {
    let bytes: Vec<u8> = image.as_flat().iter().map(|&x| to_u8(x)).collect();
    write_png(path.as_ref(), image.width(), image.height(), &bytes, image::ExtendedColorType::Rgb8)
}

/// Writes an 8-bit greyscale PNG from row-major bytes (`values.len() == width * height`).
pub fn write_gray_png(path: impl AsRef<Path>, width: usize, height: usize, values: &[u8]) -> Result<()> {
    let path = path.as_ref();
    if values.len() != width * height {
        let problem = format!("{} grey values given for a {width}x{height} image", values.len());
        return Err(DataError::invalid(path, problem));
    }
    write_png(path, width, height, values, image::ExtendedColorType::L8)
}

fn write_png(path: &Path, width: usize, height: usize, bytes: &[u8], color: image::ExtendedColorType) -> Result<()> {
    let (w, h) = png_size(path, width, height)?;
    let mut encoded = Vec::new();
    image::codecs::png::PngEncoder::new(&mut encoded)
        .write_image(bytes, w, h, color)
        .map_err(|e| DataError::image(path, "cannot encode PNG", e))?;
    write_atomically(path, &encoded)
}

fn png_size(path: &Path, width: usize, height: usize) -> Result<(u32, u32)> {
    match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => Ok((w, h)),
        _ => Err(DataError::invalid(path, format!("cannot write a {width}x{height} image"))),
    }
}

/// Reads a depth EXR: the single channel whatever its name, else the first of [`DEPTH_CHANNELS`].
/// Values are returned as stored (f16/u32 samples are converted to f32).
pub fn read_depth_exr(path: impl AsRef<Path>) -> Result<DepthMap> {
    let path = path.as_ref();
    let image = ex::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|e| DataError::exr(path, "cannot read EXR", e))?;

    // Flatten (layer, channel) so that the channel rule sees one list of full names.
    let mut channels = Vec::new();
    for layer in &image.layer_data {
        for channel in &layer.channel_data.list {
            let name = full_channel_name(layer.attributes.layer_name.as_ref(), &channel.name);
            channels.push((name, layer.size, &channel.sample_data));
        }
    }
    let names: Vec<String> = channels.iter().map(|c| c.0.clone()).collect();
    let index = pick_depth_channel(&names).ok_or_else(|| no_depth_channel(path, names))?;
    let (_, size, samples) = channels.swap_remove(index);
    let values: Vec<f32> = samples.values_as_f32().collect();
    Ok(DepthMap::from_values(size.width(), size.height(), values))
}

/// The size and depth channel of an EXR from its header only: what [`read_depth_exr`] would read.
pub(crate) fn depth_exr_size(path: &Path) -> Result<(usize, usize)> {
    let meta =
        ex::MetaData::read_from_file(path, false).map_err(|e| DataError::exr(path, "cannot read EXR header", e))?;
    let mut channels = Vec::new();
    for header in &meta.headers {
        for channel in &header.channels.list {
            let name = full_channel_name(header.own_attributes.layer_name.as_ref(), &channel.name);
            channels.push((name, header.layer_size));
        }
    }
    let names: Vec<String> = channels.iter().map(|c| c.0.clone()).collect();
    let index = pick_depth_channel(&names).ok_or_else(|| no_depth_channel(path, names))?;
    let size = channels[index].1;
    Ok((size.width(), size.height()))
}

/// A channel's name qualified by its layer's name (multi-part files), e.g. `depth.Z`.
fn full_channel_name(layer: Option<&ex::Text>, channel: &ex::Text) -> String {
    match layer {
        Some(layer) if !layer.to_string().is_empty() => format!("{layer}.{channel}"),
        _ => channel.to_string(),
    }
}

/// The index of the depth channel by the rule of ALGORITHMS.md §3, `None` when no channel qualifies.
pub fn pick_depth_channel(names: &[String]) -> Option<usize> {
    if names.len() == 1 {
        return Some(0);
    }
    DEPTH_CHANNELS.iter().find_map(|wanted| names.iter().position(|n| n == wanted))
}

fn no_depth_channel(path: &Path, channels: Vec<String>) -> DataError {
    DataError::NoDepthChannel { path: path.to_path_buf(), channels, accepted: &DEPTH_CHANNELS }
}

/// Writes a depth map as an EXR with the single f32 channel `Y`, lossless (ZIP) and byte-deterministic.
pub fn write_depth_exr(path: impl AsRef<Path>, depth: &DepthMap) -> Result<()> {
    let path = path.as_ref();
    if depth.is_empty() {
        let problem = format!("cannot write a {}x{} depth map", depth.width(), depth.height());
        return Err(DataError::invalid(path, problem));
    }
    let samples = ex::FlatSamples::F32(depth.as_flat().to_vec());
    let channel = ex::AnyChannel::new(WRITTEN_DEPTH_CHANNEL, samples);
    let channels = ex::AnyChannels::sort(ex::SmallVec::from_vec(vec![channel]));
    // ZIP keeps f32 bit-exact; increasing line order fixes the block order in the file.
    let layer = ex::Layer::new(
        (depth.width(), depth.height()),
        ex::LayerAttributes::default(),
        ex::Encoding::SMALL_LOSSLESS,
        channels,
    );
    let mut encoded = Cursor::new(Vec::new());
    ex::Image::from_layer(layer)
        .write()
        .non_parallel() // one thread: the bytes cannot depend on scheduling
        .to_buffered(&mut encoded)
        .map_err(|e| DataError::exr(path, "cannot encode EXR", e))?;
    write_atomically(path, encoded.get_ref())
}

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so that `path`
/// holds either its old content or all of the new one. The parent folder must exist.
///
/// No `fsync`: the aim is that readers never see partial files, not durability across power loss,
/// and syncing every frame would slow down writing datasets considerably. What cannot be made
/// again cheaply (checkpoints, models) goes through [`write_durably`].
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_through_temporary(path, bytes, false)
}

/// [`write_atomically`], durable across a power cut: the file is flushed to disk before the rename
/// and the folder after it, so the name holds the old bytes or the new ones, never a renamed but
/// empty file.
pub fn write_durably(path: &Path, bytes: &[u8]) -> Result<()> {
    write_through_temporary(path, bytes, true)
}

fn write_through_temporary(path: &Path, bytes: &[u8], durable: bool) -> Result<()> {
    let tmp = temporary_sibling(path)?;
    let result = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .and_then(|mut file| file.write_all(bytes).and_then(|()| if durable { file.sync_all() } else { Ok(()) }))
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => DataError::io(path, "cannot write: its folder does not exist", e),
            _ => DataError::io(&tmp, "cannot write temporary file", e),
        })
        .and_then(|()| fs::rename(&tmp, path).map_err(|e| DataError::io(path, "cannot rename temporary file onto", e)))
        .and_then(|()| if durable { sync_folder_of(path) } else { Ok(()) });
    if result.is_err() {
        let _ = fs::remove_file(&tmp); // best effort: the original error matters more
    }
    result
}

/// Makes a rename in the folder of `path` durable (the folder's entry is what the rename wrote).
fn sync_folder_of(path: &Path) -> Result<()> {
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    // Only Unix can open a folder to sync it; elsewhere the rename is as durable as it gets.
    if cfg!(unix) {
        fs::File::open(folder)
            .and_then(|f| f.sync_all())
            .map_err(|e| DataError::io(folder, "cannot sync folder", e))?;
    }
    Ok(())
}

/// A name beside `path` unique to this process and call, hidden so that listings ignore it.
fn temporary_sibling(path: &Path) -> Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| DataError::invalid(path, "not a file path"))?;
    let unique = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp_name = format!(".{}.{}-{unique}.tmp", name.to_string_lossy(), std::process::id());
    Ok(path.with_file_name(tmp_name))
}
