//! One training sample: aligned crops of everything the network and its losses read.

use std::path::PathBuf;

use ivp_core::{DepthMap, Image, Intrinsics, PixelClass, RgbImage, VectorField};

use super::crop::CropWindow;
use super::source::ClipFrames;
use super::target::{Playback, PreparedTarget, TargetFrames};

/// Where a sample was cut from.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleOrigin {
    /// The clip's number in its source.
    pub clip: u64,
    /// The clip's folder, or a description of a generated clip.
    pub clip_name: PathBuf,
    pub intrinsics: Intrinsics,
    pub direction: Playback,
    pub frames: TargetFrames,
    pub window: CropWindow,
    /// The disocclusion pixel the crop was centred on, in frame coordinates.
    pub centre: (usize, usize),
}

/// Crops (`size` x `size`, f32) for target `t = n + 1` of a clip; all share one window.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Temporal prior `(alpha^w, beta^w)` of `t` (ALGORITHMS.md §6.2): zero on the holes of `t`.
    pub prior: VectorField,
    /// `d^w_t`: depth of `n` warped into view `t`, 0 in holes.
    pub warped_depth: DepthMap,
    /// `f^w_t`: `f_n` warped into view `t`, black in holes.
    pub warped: RgbImage,
    /// 1 on the disocclusions of the warp `n -> t`, 0 elsewhere (known pixels and new regions).
    pub mask: Image<1>,
    /// `f_t`, the ground truth.
    pub truth: RgbImage,
    /// `f_n` (intensity ablation).
    pub last: RgbImage,
    /// `f^w_n`: `f_{n-2}` warped into view `n` (intensity ablation).
    pub last_warped: RgbImage,
    pub origin: SampleOrigin,
}

impl Sample {
    /// The side of the crops.
    pub fn size(&self) -> usize {
        self.origin.window.size
    }

    /// Cuts the crops of `target` centred on its disocclusion pixel number `centre_index`
    /// (an index into `target.disocclusions`).
    pub(crate) fn cut(
        clip: &ClipFrames,
        target: &PreparedTarget,
        centre_index: usize,
        size: usize,
        origin: (u64, PathBuf, Playback),
    ) -> Self {
        let width = target.warped.image.width();
        let centre_pixel = target.disocclusions[centre_index] as usize;
        let centre = (centre_pixel % width, centre_pixel / width);
        let window = CropWindow::centred_on(centre, size, clip.size());
        let classes = window.cut_field(target.warped.holes.classes(), width);
        let frames = target.frames;
        let (clip_id, clip_name, direction) = origin;
        Self {
            prior: window.cut(&target.prior),
            warped_depth: window.cut(&target.warped.depth),
            warped: window.cut(&target.warped.image),
            mask: Image::from_values(
                size,
                size,
                classes.iter().map(|&c| f32::from(u8::from(c == PixelClass::Disocclusion))).collect(),
            ),
            truth: window.cut(&clip.frames[frames.target].image),
            last: window.cut(&clip.frames[frames.last].image),
            last_warped: window.cut(&target.last_warped),
            origin: SampleOrigin {
                clip: clip_id,
                clip_name,
                intrinsics: clip.intrinsics,
                direction,
                frames,
                window,
                centre,
            },
        }
    }
}
