//! Where training clips come from: a dataset folder, a generator of synthetic scenes, or any
//! closure (tests, experiments).

use std::path::{Path, PathBuf};

use ivp_core::geometry::FrameView;
use ivp_core::{Intrinsics, WorldToCamera};

use crate::error::{DataError, Result};
use crate::{find_clips, Clip, Frame};

/// A whole clip in memory: frames, one pose per frame, shared intrinsics.
#[derive(Clone, Debug)]
pub struct ClipFrames {
    pub frames: Vec<Frame>,
    pub poses: Vec<WorldToCamera>,
    pub intrinsics: Intrinsics,
}

impl ClipFrames {
    /// Frame `i` as the prior and the infillers see it.
    pub fn view(&self, i: usize) -> FrameView<'_> {
        FrameView { image: &self.frames[i].image, depth: &self.frames[i].depth, pose: &self.poses[i] }
    }

    /// Loads every frame of an opened clip.
    pub fn load(clip: &Clip) -> Result<Self> {
        let frames = (0..clip.len()).map(|i| clip.load_frame(i)).collect::<Result<Vec<_>>>()?;
        Ok(Self { frames, poses: clip.poses().to_vec(), intrinsics: *clip.intrinsics() })
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// `(width, height)` of the frames; `(0, 0)` without frames.
    pub fn size(&self) -> (usize, usize) {
        self.frames.first().map_or((0, 0), |f| (f.image.width(), f.image.height()))
    }

    /// Checks what the sampler relies on: one pose per frame, every image and depth map of one
    /// size, and frames at least `crop` pixels wide and high. `origin` names the clip in errors.
    pub(crate) fn check(&self, origin: &Path, crop: usize) -> Result<()> {
        let problem = |what: String| Err(DataError::Sampling { origin: origin.to_path_buf(), problem: what });
        if self.poses.len() != self.frames.len() {
            return problem(format!(
                "{} poses for {} frames: one pose per frame is required",
                self.poses.len(),
                self.len()
            ));
        }
        let (width, height) = self.size();
        for (i, frame) in self.frames.iter().enumerate() {
            let sizes = [(frame.image.width(), frame.image.height()), (frame.depth.width(), frame.depth.height())];
            if sizes.iter().any(|&s| s != (width, height)) {
                return problem(format!(
                    "frame {i}: image {:?} and depth {:?} differ from frame 0's {width}x{height}",
                    sizes[0], sizes[1]
                ));
            }
        }
        if width < crop || height < crop {
            return problem(format!(
                "frames are {width}x{height}, smaller than the {crop}x{crop} training crop: use a smaller crop or larger frames"
            ));
        }
        Ok(())
    }
}

/// A collection of clips the sampler can draw from.
///
/// Clips are identified by a number `id`: `0..count` for a finite collection, any `u64` for an
/// endless one. `seed` is a per-clip seed chosen by the sampler (see
/// [`SampleGenerator`](super::SampleGenerator)); sources that generate their clips must derive them
/// from it alone, so that the same `(id, seed)` always gives the same clip.
pub trait ClipSource: Send + Sync {
    /// `Some(n)` for a finite collection of clips `0..n` (`n > 0`), `None` for an endless one.
    fn clip_count(&self) -> Option<u64>;

    /// The frames of clip `id`.
    fn load(&self, id: u64, seed: u64) -> Result<ClipFrames>;

    /// Names clip `id` in messages: its folder, or a description of a generated clip.
    fn origin(&self, id: u64, seed: u64) -> PathBuf;
}

/// Every clip of a dataset folder (ALGORITHMS.md §3), in the sorted order of [`find_clips`].
#[derive(Clone, Debug)]
pub struct DatasetSource {
    clips: Vec<Clip>,
}

impl DatasetSource {
    /// Opens every clip below `root` (cheap: frames are read when a clip is first sampled).
    pub fn open(root: impl AsRef<Path>) -> Result<Self> {
        let clips = find_clips(root)?.iter().map(Clip::open).collect::<Result<Vec<_>>>()?;
        Ok(Self { clips })
    }

    /// Errors if `clips` is empty.
    pub fn from_clips(clips: Vec<Clip>) -> Result<Self> {
        if clips.is_empty() {
            return Err(DataError::NoClip { path: PathBuf::from("(empty list of clips)") });
        }
        Ok(Self { clips })
    }

    pub fn clips(&self) -> &[Clip] {
        &self.clips
    }
}

impl ClipSource for DatasetSource {
    fn clip_count(&self) -> Option<u64> {
        Some(self.clips.len() as u64)
    }

    fn load(&self, id: u64, _seed: u64) -> Result<ClipFrames> {
        ClipFrames::load(&self.clips[id as usize])
    }

    fn origin(&self, id: u64, _seed: u64) -> PathBuf {
        self.clips[id as usize].path().to_path_buf()
    }
}

/// A source defined by a closure `(id, seed) -> ClipFrames`.
pub struct FnSource<F> {
    name: String,
    count: Option<u64>,
    load: F,
}

impl<F> FnSource<F>
where
    F: Fn(u64, u64) -> Result<ClipFrames> + Send + Sync,
{
    /// `name` appears in messages as `name clip <id>`; `count` as in [`ClipSource::clip_count`].
    pub fn new(name: impl Into<String>, count: Option<u64>, load: F) -> Self {
        Self { name: name.into(), count, load }
    }
}

impl<F> ClipSource for FnSource<F>
where
    F: Fn(u64, u64) -> Result<ClipFrames> + Send + Sync,
{
    fn clip_count(&self) -> Option<u64> {
        self.count
    }

    fn load(&self, id: u64, seed: u64) -> Result<ClipFrames> {
        (self.load)(id, seed)
    }

    fn origin(&self, id: u64, seed: u64) -> PathBuf {
        PathBuf::from(format!("{} clip {id} (seed {seed:#018x})", self.name))
    }
}
