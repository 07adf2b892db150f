//! `ivp infer` and `ivp upsample`: a trained model on one target of a clip, or on every other
//! frame of a clip to double its frame rate.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use ivp_core::geometry::image::to_u8;
use ivp_core::geometry::FrameView;
use ivp_core::inference::{ModelInfiller, ModelPrediction};
use ivp_core::infill::{classical_infiller, InfillContext};
use ivp_core::nn::tensor::to_tensor;
use ivp_core::prior::{background_depth_threshold, target_prior};
use ivp_core::{DepthMap, RgbImage, Warp};
use ivp_data::{write_gray_png, write_rgb_png, Clip, Frame};

use crate::eval::warp_to_target;
use crate::sheet::{gray_to_rgb, vectors_to_rgb};

/// Predicts frame `t` of `clip` from frames `t - 1` and (when it exists) `t - 3`, as the
/// evaluation does. Without frame `t - 3` the model runs without its temporal prior.
pub fn predict_target(model: &ModelInfiller, clip: &Clip, t: usize) -> Result<(ModelPrediction, Warp)> {
    if t == 0 || t >= clip.len() {
        bail!("{}: target {t} must be in 1..={} (it needs the frame before it)", clip.path().display(), clip.len() - 1);
    }
    let last = clip.load_frame(t - 1)?;
    let before_last: Option<Frame> = if t >= 3 { Some(clip.load_frame(t - 3)?) } else { None };
    let warp = warp_to_target(clip, &last, t);
    let ctx = InfillContext {
        intrinsics: clip.intrinsics(),
        last: FrameView { image: &last.image, depth: &last.depth, pose: clip.pose(t - 1) },
        before_last: before_last.as_ref().map(|f| FrameView {
            image: &f.image,
            depth: &f.depth,
            pose: clip.pose(t - 3),
        }),
        target_pose: clip.pose(t),
        warped: &warp,
        ground_truth: None,
    };
    let prediction = model.predict(&ctx).with_context(|| format!("{}: target {t}", clip.path().display()))?;
    Ok((prediction, warp))
}

/// Writes what the network of `ivp infer --iterations 1` reads for target `t` of `clip` (at scale 1,
/// in one dense pass), and what turns its vectors into the predicted frame, as one safetensors file
/// of (1, C, H, W) f32 tensors: the graph's inputs `prior`, `depth` and `hole` (MODEL.md), the
/// warped frame `warped` (0 in holes), `known` (1 on the pixels the warp covered), `fill` (the `fill`
/// method's frame: where a vector reads nothing, even walked, or reads the foreground, the pixel
/// takes its value), `threshold` (each disocclusion pixel's background depth threshold, 0 where it
/// has none and off the disocclusions: a read of depth `d` with `d * FOREGROUND_DEPTH_RATIO <
/// threshold` takes the `fill` value) and the target frame `truth`. `examples/onnx/run_onnx.py`
/// infills and scores from it.
pub fn write_network_inputs(clip: &Clip, t: usize, path: &Path) -> Result<()> {
    if t < 3 || t >= clip.len() {
        bail!(
            "{}: target {t} needs frames {}..={t} (the prior reads frame t-3)",
            clip.path().display(),
            t.saturating_sub(3)
        );
    }
    let (last, before_last) = (clip.load_frame(t - 1)?, clip.load_frame(t - 3)?);
    let warp = warp_to_target(clip, &last, t);
    let ctx = crate::eval::target_context(clip, [&before_last, &last], t, &warp, None);
    let known = warp.holes.known();
    let before_last_view = ctx.before_last.as_ref().expect("target_context gives frame t-3");
    let prior = target_prior(before_last_view, &ctx.last, ctx.target_pose, ctx.intrinsics, &known).prior;
    let as_map = |mask: &[bool]| {
        DepthMap::from_fn(warp.depth.width(), warp.depth.height(), |x, y| {
            [f32::from(u8::from(mask[y * warp.depth.width() + x]))]
        })
    };
    let thresholds = background_depth_threshold(&known, &warp.depth);
    let disocclusions = warp.holes.disocclusions();
    let threshold = DepthMap::from_fn(warp.depth.width(), warp.depth.height(), |x, y| {
        let i = y * warp.depth.width() + x;
        [if disocclusions[i] { thresholds[i].unwrap_or(0.0) } else { 0.0 }]
    });
    let fill = classical_infiller("fill").expect("`fill` is a classical method").infill(&ctx)?.image;
    let truth = clip.load_frame(t)?.image;
    let tensors = [
        ("prior", to_tensor(&prior)?),
        // The warp leaves 0 in its holes: the infilling's depth input as it is.
        ("depth", to_tensor(&warp.depth)?),
        ("hole", to_tensor(&as_map(&disocclusions))?),
        ("warped", to_tensor(&warp.image)?),
        ("known", to_tensor(&as_map(&known))?),
        ("fill", to_tensor(&fill)?),
        ("threshold", to_tensor(&threshold)?),
        ("truth", to_tensor(&truth)?),
    ];
    let metadata = std::collections::HashMap::from([
        ("clip".to_string(), clip.path().display().to_string()),
        ("target".to_string(), t.to_string()),
    ]);
    let bytes = safetensors::serialize(tensors, Some(metadata))?;
    ivp_data::write_atomically(path, &bytes)?;
    Ok(())
}

/// The files `ivp infer` writes, as written.
pub struct InferOutputs {
    pub files: Vec<PathBuf>,
    /// Mean absolute error on 0..255 over the disocclusions, when the ground truth exists.
    pub disocclusion_mae: Option<f64>,
}

/// `ivp infer`: `infilled.png`, `holes.png`, `vectors.png` and, with a ground truth, `error.png`.
pub fn run_infer(model: &ModelInfiller, clip: &Clip, t: usize, out: &Path) -> Result<InferOutputs> {
    let (prediction, warp) = predict_target(model, clip, t)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut files = Vec::new();
    let mut write_png = |name: &str, image: &RgbImage| -> Result<()> {
        let path = out.join(name);
        write_rgb_png(&path, image)?;
        files.push(path);
        Ok(())
    };
    write_png("infilled.png", &prediction.image)?;
    let holes = &warp.holes;
    let holes_path = out.join("holes.png");
    write_gray_png(&holes_path, holes.width(), holes.height(), &holes.to_gray8())?;
    if let Some(vectors) = &prediction.vectors {
        write_png("vectors.png", &vectors_to_rgb(vectors, None))?;
    }
    let truth = clip.load_frame(t)?.image;
    let error = absolute_error(&prediction.image.quantized_to_8bit(), &truth);
    write_png(
        "error.png",
        &gray_to_rgb(
            truth.width(),
            truth.height(),
            &error.iter().map(|e| (4.0 * e).min(255.0) as u8).collect::<Vec<_>>(),
        ),
    )?;
    let disocclusions = holes.disocclusions();
    let (sum, n) =
        error.iter().zip(&disocclusions).filter(|(_, &d)| d).fold((0.0, 0usize), |(s, n), (e, _)| (s + e, n + 1));
    files.insert(1, holes_path);
    Ok(InferOutputs { files, disocclusion_mae: (n > 0).then(|| sum / n as f64) })
}

/// Mean absolute error over the channels of each pixel, on 0..255.
fn absolute_error(a: &RgbImage, b: &RgbImage) -> Vec<f64> {
    a.pixels()
        .iter()
        .zip(b.pixels())
        .map(|(p, q)| p.iter().zip(q).map(|(x, y)| (x - y).abs() as f64 * 255.0).sum::<f64>() / 3.0)
        .collect()
}

/// What `ivp upsample` did.
pub struct UpsampleSummary {
    pub frames: usize,
    pub predicted: usize,
    /// Mean D-MSE (0..255) of the predicted frames that have disocclusions.
    pub d_mse: Option<f64>,
    pub ms_per_predicted_frame: f64,
    pub preview: PathBuf,
}

/// `ivp upsample`: the even frames of `clip` are the rendered ones; every odd frame is predicted
/// from the rendered frames before it (causally). Writes `OUT/frames/NNNN.png` (the doubled
/// sequence) and `OUT/preview.gif` (prediction beside the ground truth).
pub fn run_upsample(
    model: &ModelInfiller,
    clip: &Clip,
    out: &Path,
    mut on_frame: impl FnMut(usize),
) -> Result<UpsampleSummary> {
    let frames_dir = out.join("frames");
    std::fs::create_dir_all(&frames_dir).with_context(|| format!("cannot create {}", frames_dir.display()))?;
    let mut preview = Vec::with_capacity(clip.len());
    let (mut d_mse_sum, mut d_frames, mut predicted, mut time) = (0.0, 0usize, 0usize, std::time::Duration::ZERO);
    for t in 0..clip.len() {
        let truth = clip.load_frame(t)?.image;
        let image = if t % 2 == 0 {
            truth.clone()
        } else {
            let started = std::time::Instant::now();
            let (prediction, warp) = predict_target(model, clip, t)?;
            time += started.elapsed();
            predicted += 1;
            let image = prediction.image.quantized_to_8bit();
            if let Some(d) = ivp_core::metrics::masked_mse(&image, &truth, &warp.holes.disocclusions()) {
                d_mse_sum += d;
                d_frames += 1;
            }
            image
        };
        write_rgb_png(frames_dir.join(format!("{t:04}.png")), &image)?;
        preview.push(side_by_side(&image, &truth, t % 2 == 1));
        on_frame(t);
    }
    let preview_path = out.join("preview.gif");
    write_gif(&preview_path, &preview)?;
    Ok(UpsampleSummary {
        frames: clip.len(),
        predicted,
        d_mse: (d_frames > 0).then(|| d_mse_sum / d_frames as f64),
        ms_per_predicted_frame: time.as_secs_f64() * 1e3 / predicted.max(1) as f64,
        preview: preview_path,
    })
}

/// Largest side of one panel of the preview; larger frames are shrunk by a whole factor.
const PREVIEW_PANEL: usize = 480;

/// The output frame (left, labelled "ivp" on predicted frames, "rendered" otherwise) beside the
/// ground truth (right), shrunk so that each panel is at most `PREVIEW_PANEL` wide.
fn side_by_side(output: &RgbImage, truth: &RgbImage, predicted: bool) -> RgbImage {
    let factor = output.width().div_ceil(PREVIEW_PANEL).max(1);
    let (w, h) = (output.width() / factor, output.height() / factor);
    let mut sheet = RgbImage::zeros(2 * w, h);
    for (panel, image) in [output, truth].into_iter().enumerate() {
        for v in 0..h {
            for u in 0..w {
                sheet.set(panel * w + u, v, image.get(u * factor, v * factor));
            }
        }
    }
    let label = if predicted { "ivp" } else { "rendered" };
    crate::sheet::draw_text_in(&mut sheet, 4, 4, label, w, [1.0, 1.0, 0.2]);
    crate::sheet::draw_text_in(&mut sheet, w + 4, 4, "truth", w, [1.0, 1.0, 0.2]);
    sheet
}

/// An endlessly looping GIF at about 30 frames per second, written atomically.
fn write_gif(path: &Path, frames: &[RgbImage]) -> Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let mut bytes = Vec::new();
    {
        let mut encoder = GifEncoder::new_with_speed(&mut bytes, 10);
        encoder.set_repeat(Repeat::Infinite)?;
        for f in frames {
            let rgba: Vec<u8> = f.pixels().iter().flat_map(|p| [to_u8(p[0]), to_u8(p[1]), to_u8(p[2]), 255]).collect();
            let buffer =
                image::RgbaImage::from_raw(f.width() as u32, f.height() as u32, rgba).expect("4 bytes a pixel");
            let delay = image::Delay::from_numer_denom_ms(100, 3);
            encoder.encode_frame(image::Frame::from_parts(buffer, 0, 0, delay))?;
        }
    }
    ivp_data::write_atomically(path, &bytes)?;
    Ok(())
}
