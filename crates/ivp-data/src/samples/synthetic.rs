//! Endless procedural clips ([`crate::scene`]), rendered on demand.

use std::path::PathBuf;

use super::source::{ClipFrames, ClipSource};
use crate::error::Result;
use crate::scene::{render_clip, SceneParams, SyntheticClip};

impl From<SyntheticClip> for ClipFrames {
    fn from(clip: SyntheticClip) -> Self {
        Self { frames: clip.frames, poses: clip.poses, intrinsics: clip.intrinsics }
    }
}

/// Generated scenes: clip `id` is [`render_clip`]`(seed, params)` with the seed the sampler
/// derives from its own seed, the split and `id`, so training and validation never share a scene.
///
/// With several frame scales ([`SyntheticSource::with_scales`]) each clip is rendered at
/// `params`' size times one of them, drawn from its seed: the same scene, camera and motion seen by
/// a sensor with `scale` times the pixels, so its holes are `scale` times wider in pixels. That
/// is how training sees the hole widths of 1080p frames without rendering 1080p.
///
/// With several motion scales ([`SyntheticSource::with_motion_scales`]) each clip's camera moves
/// `params.motion_scale` times one of them per frame, also drawn from its seed: the holes widen
/// with the motion at the same frame size, so wide holes cost no more to render than narrow ones.
#[derive(Clone, Debug)]
pub struct SyntheticSource {
    params: SceneParams,
    scales: Vec<usize>,
    motion_scales: Vec<f64>,
}

impl SyntheticSource {
    /// Frame size used by [`SyntheticSource::for_crops_of_256`]: 256x256 crops fit with room to move.
    pub const TRAINING_SIZE: (usize, usize) = (512, 384);

    pub fn new(params: SceneParams) -> Self {
        Self { params, scales: vec![1], motion_scales: vec![1.0] }
    }

    /// Clips rendered at `params`' size times one of `scales` (each a whole number of at least 1;
    /// an empty list means `[1]`), chosen per clip from its seed.
    pub fn with_scales(self, scales: &[usize]) -> Self {
        let scales = if scales.is_empty() { vec![1] } else { scales.iter().map(|&s| s.max(1)).collect() };
        Self { scales, ..self }
    }

    /// Clips whose camera moves `params.motion_scale` times one of `scales` per frame (each finite
    /// and positive; an empty list means `[1]`), chosen per clip from its seed independently of the
    /// frame scale.
    pub fn with_motion_scales(self, scales: &[f64]) -> Self {
        let motion_scales = if scales.is_empty() { vec![1.0] } else { scales.to_vec() };
        Self { motion_scales, ..self }
    }

    /// The scene parameters of the clip of `seed`: `params` at the clip's frame and motion scales.
    pub fn params_for(&self, seed: u64) -> SceneParams {
        // The seed is already a hash of the sampler's seed, split and clip id: its low bits and its
        // high bits are uniform, unrelated to each other and to the scene the renderer draws from
        // the whole seed.
        let scale = self.scales[(seed % self.scales.len() as u64) as usize];
        let motion = self.motion_scales[((seed >> 32) % self.motion_scales.len() as u64) as usize];
        SceneParams {
            width: self.params.width * scale,
            height: self.params.height * scale,
            motion_scale: self.params.motion_scale * motion,
            ..self.params.clone()
        }
    }

    /// The scene defaults at 512x384, so that the reference's 256x256 crops fit.
    pub fn for_crops_of_256() -> Self {
        let (width, height) = Self::TRAINING_SIZE;
        Self::new(SceneParams { width, height, ..SceneParams::default() })
    }

    pub fn params(&self) -> &SceneParams {
        &self.params
    }
}

impl ClipSource for SyntheticSource {
    fn clip_count(&self) -> Option<u64> {
        None
    }

    fn load(&self, _id: u64, seed: u64) -> Result<ClipFrames> {
        Ok(render_clip(seed, &self.params_for(seed)).into())
    }

    fn origin(&self, id: u64, seed: u64) -> PathBuf {
        let SceneParams { width, height, .. } = self.params_for(seed);
        PathBuf::from(format!("synthetic clip {id} (render seed {seed:#018x}, {width}x{height})"))
    }
}
