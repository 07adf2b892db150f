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
#[derive(Clone, Debug)]
pub struct SyntheticSource {
    params: SceneParams,
}

impl SyntheticSource {
    /// Frame size used by [`SyntheticSource::for_crops_of_256`]: 256x256 crops fit with room to move.
    pub const TRAINING_SIZE: (usize, usize) = (512, 384);

    pub fn new(params: SceneParams) -> Self {
        Self { params }
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
        Ok(render_clip(seed, &self.params).into())
    }

    fn origin(&self, id: u64, seed: u64) -> PathBuf {
        let SceneParams { width, height, .. } = self.params;
        PathBuf::from(format!("synthetic clip {id} (render seed {seed:#018x}, {width}x{height})"))
    }
}
