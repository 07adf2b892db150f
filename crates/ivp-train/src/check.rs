//! `ivp check`: validates a clip and diagnoses the usual convention mistakes by warping frame `n`
//! to `n + 1` under each reading of the files and seeing which one explains the images best.

use anyhow::Result;
use glam::DMat4;
use ivp_core::{relative_pose, warp_forward, DepthMap, Image, Intrinsics, RgbImage, WorldToCamera};
use ivp_data::Clip;

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

#[derive(Clone, Debug)]
pub struct CheckReport {
    pub frames: usize,
    pub width: usize,
    pub height: usize,
    /// Error of simply repeating the frame: a warp that does not beat it explains nothing.
    pub copy_mae: f64,
    pub fits: Vec<ReadingFit>,
    pub pairs: Vec<(usize, usize)>,
}

impl CheckReport {
    /// The reading that fits best among those that cover most of the frame.
    pub fn best(&self) -> &ReadingFit {
        let max_known = self.fits.iter().map(|f| f.known_fraction).fold(0.0, f64::max);
        self.fits
            .iter()
            .filter(|f| f.known_fraction >= 0.5 * max_known)
            .min_by(|a, b| a.mae.total_cmp(&b.mae))
            .expect("at least one reading")
    }

    /// True when the clip reads correctly as given.
    pub fn passes(&self) -> bool {
        let best = self.best();
        let as_given = &self.fits[0];
        best.reading == Reading::AsGiven
            || (as_given.mae <= best.mae * 1.05 && as_given.known_fraction >= 0.9 * best.known_fraction)
    }

    pub fn verdict(&self) -> String {
        let best = self.best();
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
    Ok(CheckReport { frames: n, width: clip.width(), height: clip.height(), copy_mae: copy_mae / count, fits, pairs })
}
