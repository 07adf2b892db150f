//! `ivp check`: validates a clip and diagnoses the usual convention mistakes by warping frame `n`
//! to `n + 1` under each reading of the files and seeing which one explains the images best.
//!
//! Causes that no reading can fix come first and are named as such: `Clip::open` refuses non-rigid
//! poses and implausible intrinsics, and the depth of every frame is counted ([`DepthStats`]); a
//! frame without usable depth makes the clip a PROBLEM before any reading is compared, and a warp
//! that covers nothing or does not beat repeating the frame is never called OK.

use anyhow::Result;
use glam::DMat4;
use ivp_core::{relative_pose, warp_forward, DepthMap, Image, Intrinsics, RgbImage, WorldToCamera};
use ivp_data::{Clip, DepthStats};

/// One way of reading a clip's poses and depth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reading {
    AsGiven,
    CameraToWorld,
    OpenGlAxes,
    CameraToWorldOpenGl,
    Millimetres,
    RayLength,
}

impl Reading {
    pub const ALL: [Reading; 6] = [
        Reading::AsGiven,
        Reading::CameraToWorld,
        Reading::OpenGlAxes,
        Reading::CameraToWorldOpenGl,
        Reading::Millimetres,
        Reading::RayLength,
    ];

    pub fn describe(self) -> &'static str {
        match self {
            Reading::AsGiven => "as given (world-to-camera, OpenCV axes, planar depth)",
            Reading::CameraToWorld => "poses are camera-to-world",
            Reading::OpenGlAxes => "poses use OpenGL axes (y up, z backward)",
            Reading::CameraToWorldOpenGl => "poses are camera-to-world with OpenGL axes (Blender's matrix_world)",
            Reading::Millimetres => "depth is in millimetres",
            Reading::RayLength => "depth is ray length, not planar depth",
        }
    }

    /// What to do about it when this reading fits best.
    pub fn advice(self) -> &'static str {
        match self {
            Reading::AsGiven => "nothing: the clip follows ivp's conventions",
            Reading::CameraToWorld => "invert every matrix of TransformationMatrices.csv",
            Reading::OpenGlAxes => "left-multiply every matrix by diag(1, -1, -1, 1)",
            Reading::CameraToWorldOpenGl => "invert every matrix, then left-multiply it by diag(1, -1, -1, 1)",
            Reading::Millimetres => "divide the depth maps by 1000 (or multiply the translations by 1000)",
            Reading::RayLength => "convert depth to planar: z = r / |K^-1 [u, v, 1]|",
        }
    }

    fn pose(self, e: &WorldToCamera) -> WorldToCamera {
        let flip = DMat4::from_diagonal(glam::DVec4::new(1.0, -1.0, -1.0, 1.0));
        match self {
            Reading::CameraToWorld => WorldToCamera(e.0.inverse()),
            Reading::OpenGlAxes => WorldToCamera(flip * e.0),
            Reading::CameraToWorldOpenGl => WorldToCamera(flip * e.0.inverse()),
            _ => *e,
        }
    }

    fn depth(self, d: &DepthMap, k: &Intrinsics) -> DepthMap {
        match self {
            Reading::Millimetres => {
                Image::from_values(d.width(), d.height(), d.as_flat().iter().map(|z| z / 1000.0).collect())
            }
            Reading::RayLength => Image::from_fn(d.width(), d.height(), |u, v| {
                [(d.at(u, v) as f64 / k.ray_length_per_depth(u as f64, v as f64)) as f32]
            }),
            _ => d.clone(),
        }
    }
}

/// How well one reading explains the motion between frames.
#[derive(Clone, Debug)]
pub struct ReadingFit {
    pub reading: Reading,
    /// Mean absolute error on known pixels, 0..255 scale.
    pub mae: f64,
    /// Fraction of the target frame that the warp covers.
    pub known_fraction: f64,
}

/// Below this share of the target frame covered, a warp explains nothing, whatever its error.
pub const MIN_KNOWN_FRACTION: f64 = 0.05;

/// The depth of one frame as `ivp check` reports it.
#[derive(Clone, Debug)]
pub struct FrameDepth {
    pub frame: usize,
    pub path: std::path::PathBuf,
    pub stats: DepthStats,
}

#[derive(Clone, Debug)]
pub struct CheckReport {
    pub frames: usize,
    pub width: usize,
    pub height: usize,
    /// The depth of every frame, in frame order.
    pub depth: Vec<FrameDepth>,
    /// Error of simply repeating the frame: a warp that does not beat it explains nothing.
    pub copy_mae: f64,
    /// Empty when some frame has no usable depth (no reading is compared then).
    pub fits: Vec<ReadingFit>,
    pub pairs: Vec<(usize, usize)>,
}

impl CheckReport {
    /// The depth counts of every frame added up.
    pub fn total_depth(&self) -> DepthStats {
        self.depth.iter().fold(DepthStats::default(), |a, d| DepthStats {
            pixels: a.pixels + d.stats.pixels,
            usable: a.usable + d.stats.usable,
            far: a.far + d.stats.far,
            missing: a.missing + d.stats.missing,
            implausible: a.implausible + d.stats.implausible,
            invalid: a.invalid + d.stats.invalid,
        })
    }

    /// Frames without a single usable depth value.
    pub fn unusable_depth(&self) -> Vec<&FrameDepth> {
        self.depth.iter().filter(|d| !d.stats.is_usable()).collect()
    }

    /// Frames with a large share of invalid or implausible depth values (usable otherwise).
    pub fn suspicious_depth(&self) -> Vec<&FrameDepth> {
        self.depth.iter().filter(|d| d.stats.is_usable() && d.stats.is_suspicious()).collect()
    }

    /// The reading that fits best among those that cover most of the frame (None when no reading
    /// was compared).
    pub fn best(&self) -> Option<&ReadingFit> {
        let max_known = self.fits.iter().map(|f| f.known_fraction).fold(0.0, f64::max);
        self.fits.iter().filter(|f| f.known_fraction >= 0.5 * max_known).min_by(|a, b| a.mae.total_cmp(&b.mae))
    }

    /// Why a reading's warp explains nothing, if it does not: it covers (almost) nothing, or it is
    /// clearly worse than repeating the frame (by more than 5%, which resampling alone never costs).
    fn explains_nothing(&self, fit: &ReadingFit) -> Option<String> {
        if !fit.mae.is_finite() || fit.known_fraction < MIN_KNOWN_FRACTION {
            Some(format!(
                "the warp covers only {:.1}% of the frame: check the depth units and the intrinsics",
                100.0 * fit.known_fraction
            ))
        } else if self.copy_mae > 0.0 && fit.mae > 1.05 * self.copy_mae {
            Some(format!(
                "the warp (error {:.2}) is worse than repeating the frame ({:.2}): the poses, depth and intrinsics \
                 do not describe the same camera",
                fit.mae, self.copy_mae
            ))
        } else {
            None
        }
    }

    /// True when the clip reads correctly as given: every frame has usable depth, the warp as given
    /// explains the motion, and no other reading explains it clearly better.
    pub fn passes(&self) -> bool {
        let Some(best) = self.best() else { return false };
        let as_given = &self.fits[0];
        if !self.unusable_depth().is_empty() || self.explains_nothing(as_given).is_some() {
            return false;
        }
        best.reading == Reading::AsGiven
            || (as_given.mae <= best.mae * 1.05 && as_given.known_fraction >= 0.9 * best.known_fraction)
    }

    pub fn verdict(&self) -> String {
        let unusable = self.unusable_depth();
        if !unusable.is_empty() {
            let frames: Vec<String> =
                unusable.iter().take(8).map(|d| format!("{} ({})", d.frame, d.path.display())).collect();
            let more = if unusable.len() > 8 { format!(" and {} more", unusable.len() - 8) } else { String::new() };
            return format!(
                "PROBLEM: no usable depth in {} of {} frames: {}{more}. Depth must be finite, positive planar depth \
                 between {:e} and {:e} scene units (+inf for sky and 0 for missing are allowed but not warped).",
                unusable.len(),
                self.frames,
                frames.join(", "),
                ivp_data::MIN_PLAUSIBLE_DEPTH,
                ivp_data::MAX_PLAUSIBLE_DEPTH
            );
        }
        let Some(best) = self.best() else { return "PROBLEM: no frame pair could be warped".into() };
        if !self.passes() {
            // Blame a convention only when its reading explains the motion; otherwise say what fails.
            let blame_reading = best.reading != Reading::AsGiven && self.explains_nothing(best).is_none();
            if !blame_reading {
                let why = self.explains_nothing(&self.fits[0]).or_else(|| self.explains_nothing(best));
                let why = why.unwrap_or_else(|| "the warps do not beat repeating the frame".into());
                return format!("PROBLEM: no reading of the clip explains the motion: {why}.");
            }
        }
        if self.passes() {
            format!(
                "OK: the clip reads correctly as given (mean absolute error {:.2} on known pixels, {:.1}% covered; repeating the frame gives {:.2})",
                self.fits[0].mae,
                100.0 * self.fits[0].known_fraction,
                self.copy_mae
            )
        } else {
            format!(
                "PROBLEM: the clip fits best if {} (error {:.2} against {:.2} as given). Fix: {}.",
                best.reading.describe(),
                best.mae,
                self.fits[0].mae,
                best.reading.advice()
            )
        }
    }
}

/// Mean absolute error (0..255) over the pixels where `known` is set, and the known fraction.
fn known_pixel_error(pred: &RgbImage, truth: &RgbImage, known: &[bool]) -> (f64, f64) {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for ((p, q), &k) in pred.pixels().iter().zip(truth.pixels()).zip(known) {
        if k {
            sum += p.iter().zip(q).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / 3.0;
            n += 1;
        }
    }
    (if n == 0 { f64::INFINITY } else { 255.0 * sum / n as f64 }, n as f64 / known.len().max(1) as f64)
}

/// Warps a few frame pairs `n -> n + 1` under every reading (the clip must open cleanly first).
pub fn check_clip(clip: &Clip) -> Result<CheckReport> {
    let n = clip.len();
    anyhow::ensure!(n >= 2, "{}: a clip needs at least 2 frames to check motion, it has {n}", clip.path().display());
    // The start, the middle and the end of the clip.
    let mut pairs: Vec<(usize, usize)> = [0, (n - 2) / 2, n - 2].iter().map(|&i| (i, i + 1)).collect();
    pairs.dedup();

    let mut depth = Vec::with_capacity(n);
    for frame in 0..n {
        depth.push(FrameDepth { frame, path: clip.depth_path(frame).to_path_buf(), stats: clip.depth_stats(frame)? });
    }
    let mut report = CheckReport {
        frames: n,
        width: clip.width(),
        height: clip.height(),
        depth,
        copy_mae: 0.0,
        fits: Vec::new(),
        pairs: pairs.clone(),
    };
    if !report.unusable_depth().is_empty() {
        return Ok(report);
    }

    let k = clip.intrinsics();
    let mut sums = vec![(0.0, 0.0); Reading::ALL.len()];
    let mut copy_mae = 0.0;
    for &(a, b) in &pairs {
        let (src, dst) = (clip.load_frame(a)?, clip.load_frame(b)?);
        copy_mae += known_pixel_error(&src.image, &dst.image, &vec![true; src.image.len()]).0;
        for (reading, sum) in Reading::ALL.iter().zip(sums.iter_mut()) {
            let transform = relative_pose(&reading.pose(clip.pose(a)), &reading.pose(clip.pose(b)));
            let warp = warp_forward(&src.image, &reading.depth(&src.depth, k), k, &transform);
            let (mae, known) = known_pixel_error(&warp.image, &dst.image, &warp.holes.known());
            sum.0 += mae;
            sum.1 += known;
        }
    }
    let count = pairs.len() as f64;
    let fits = Reading::ALL
        .iter()
        .zip(sums)
        .map(|(&reading, (mae, known))| ReadingFit { reading, mae: mae / count, known_fraction: known / count })
        .collect();
    report.copy_mae = copy_mae / count;
    report.fits = fits;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(fits: &[(f64, f64)], copy_mae: f64, depth: DepthStats) -> CheckReport {
        CheckReport {
            frames: 2,
            width: 4,
            height: 4,
            depth: vec![FrameDepth { frame: 1, path: "/clip/depth/0001.exr".into(), stats: depth }],
            copy_mae,
            fits: Reading::ALL
                .iter()
                .zip(fits)
                .map(|(&reading, &(mae, known_fraction))| ReadingFit { reading, mae, known_fraction })
                .collect(),
            pairs: vec![(0, 1)],
        }
    }

    const GOOD_DEPTH: DepthStats =
        DepthStats { pixels: 16, usable: 16, far: 0, missing: 0, implausible: 0, invalid: 0 };
    const OTHERS: [(f64, f64); 5] = [(9.0, 0.9); 5];

    fn with(as_given: (f64, f64)) -> Vec<(f64, f64)> {
        std::iter::once(as_given).chain(OTHERS).collect()
    }

    #[test]
    fn a_good_clip_passes() {
        let r = report(&with((1.5, 0.97)), 9.0, GOOD_DEPTH);
        assert!(r.passes() && r.verdict().starts_with("OK"), "{}", r.verdict());
    }

    #[test]
    fn a_warp_that_covers_nothing_is_never_ok() {
        let fits = vec![(f64::INFINITY, 0.0); 6];
        let r = report(&fits, 9.0, GOOD_DEPTH);
        assert!(!r.passes());
        assert!(r.verdict().contains("covers only 0.0%") && !r.verdict().contains("fits best if"), "{}", r.verdict());
    }

    #[test]
    fn a_warp_worse_than_repeating_the_frame_is_not_ok() {
        let fits: Vec<_> = std::iter::once((12.0, 0.95)).chain([(14.0, 0.9); 5]).collect();
        let r = report(&fits, 9.0, GOOD_DEPTH);
        assert!(!r.passes());
        assert!(r.verdict().contains("worse than repeating the frame"), "{}", r.verdict());
    }

    #[test]
    fn unusable_depth_is_named_before_any_reading() {
        let none = DepthStats { pixels: 16, usable: 0, far: 0, missing: 0, implausible: 0, invalid: 16 };
        let r = report(&[], 0.0, none);
        assert!(!r.passes());
        let v = r.verdict();
        assert!(v.contains("no usable depth in 1 of 2 frames") && v.contains("/clip/depth/0001.exr"), "{v}");
    }
}
