//! A clip: numbered frames (image + depth) with one camera pose each and shared intrinsics.

use std::fs;
use std::path::{Path, PathBuf};

use ivp_core::{DepthMap, Intrinsics, RgbImage, WorldToCamera};

use crate::csv::{check_intrinsics, read_intrinsics, read_poses, INTRINSICS_FILE, POSES_FILE};
use crate::depth::{check_depth, DepthStats};
use crate::error::{DataError, Result};
use crate::frames::{list_frames, FrameFiles, Layout};
use crate::io::{depth_exr_size, image_size, read_depth_exr, read_rgb};
use crate::scenenet::read_scenenet_depth;

/// The two layouts a clip folder may have (ALGORITHMS.md §3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClipFormat {
    /// `rgb/NNNN.png`, `depth/NNNN.exr` (planar depth).
    IiscVeed,
    /// `photo/<n>.jpg`, `depth/<n>.png` (u16 millimetres of ray length), n = 0, 25, 50, ...
    SceneNet,
}

impl ClipFormat {
    pub(crate) fn layout(self) -> Layout {
        match self {
            Self::IiscVeed => Layout::IISC_VEED,
            Self::SceneNet => Layout::SCENENET,
        }
    }

    /// The format's fixed camera and the only frame size it is valid for.
    fn default_camera(self) -> (Intrinsics, (usize, usize)) {
        match self {
            Self::IiscVeed => (Intrinsics::iisc_veed_default(), (1920, 1080)),
            Self::SceneNet => (Intrinsics::scenenet_default(), (320, 240)),
        }
    }
}

/// One frame in memory: sRGB colours in `[0, 1]` and planar depth.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub image: RgbImage,
    pub depth: DepthMap,
}

/// An opened clip. Frames stay on disk until loaded (1080p clips are large); [`Clip::open`] has
/// already checked everything that headers and CSV files can tell.
#[derive(Clone, Debug)]
pub struct Clip {
    path: PathBuf,
    format: ClipFormat,
    files: Vec<FrameFiles>,
    poses: Vec<WorldToCamera>,
    intrinsics: Intrinsics,
    width: usize,
    height: usize,
}

impl Clip {
    /// Opens a clip folder in either layout and validates it cheaply: frame files pair up without
    /// gaps, one finite rigid pose per frame (`read_poses`), plausible intrinsics for the frame size
    /// (`check_intrinsics`), and every image and depth header has the same size. Pixel data is not
    /// read.
    pub fn open(dir: impl AsRef<Path>) -> Result<Clip> {
        let path = dir.as_ref().to_path_buf();
        let format = detect_format(&path)?;
        let files = list_frames(&path, &format.layout())?;
        let poses = read_poses(&path.join(POSES_FILE))?;
        check_pose_count(&path, &files, poses.len())?;
        let (width, height) = common_size(format, &files)?;
        let intrinsics = clip_intrinsics(&path, format, (width, height))?;
        tracing::debug!(clip = %path.display(), frames = files.len(), width, height, ?format, "opened clip");
        Ok(Clip { path, format, files, poses, intrinsics, width, height })
    }

    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// Always false for an opened clip (`open` refuses clips without frames).
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn format(&self) -> ClipFormat {
        self.format
    }

    pub fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }

    /// World-to-camera poses, one per frame in frame order.
    pub fn poses(&self) -> &[WorldToCamera] {
        &self.poses
    }

    /// The pose of frame `i`. Panics if `i >= len()`.
    pub fn pose(&self, i: usize) -> &WorldToCamera {
        &self.poses[i]
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The numbers in the file names, in frame order (`0, 1, ...` or SceneNet's `0, 25, ...`).
    pub fn frame_numbers(&self) -> Vec<u64> {
        self.files.iter().map(|f| f.number).collect()
    }

    /// The image file of frame `i`. Panics if `i >= len()`.
    pub fn image_path(&self, i: usize) -> &Path {
        &self.files[i].image
    }

    /// The depth file of frame `i`. Panics if `i >= len()`.
    pub fn depth_path(&self, i: usize) -> &Path {
        &self.files[i].depth
    }

    /// The colour image of frame `i`.
    pub fn load_image(&self, i: usize) -> Result<RgbImage> {
        let path = &self.frame_files(i)?.image;
        let image = read_rgb(path)?;
        self.check_size(path, image.width(), image.height())?;
        Ok(image)
    }

    /// The planar depth of frame `i`, whatever the format stores. A map without a usable value is
    /// an error; one with many invalid or implausible values gets a warning (see [`DepthStats`]).
    pub fn load_depth(&self, i: usize) -> Result<DepthMap> {
        Ok(self.load_depth_with_stats(i)?.0)
    }

    /// [`Clip::load_depth`] with the counts of each class of depth value.
    pub fn load_depth_with_stats(&self, i: usize) -> Result<(DepthMap, DepthStats)> {
        let (depth, stats) = self.read_depth(i)?;
        check_depth(self.depth_path(i), &stats)?;
        Ok((depth, stats))
    }

    /// The counts of each class of depth value of frame `i`, without refusing a frame that has no
    /// usable depth (for `ivp check`, which reports every frame). Unreadable files are still errors.
    pub fn depth_stats(&self, i: usize) -> Result<DepthStats> {
        Ok(self.read_depth(i)?.1)
    }

    fn read_depth(&self, i: usize) -> Result<(DepthMap, DepthStats)> {
        let path = &self.frame_files(i)?.depth;
        let depth = match self.format {
            ClipFormat::IiscVeed => read_depth_exr(path)?,
            ClipFormat::SceneNet => read_scenenet_depth(path, &self.intrinsics)?,
        };
        self.check_size(path, depth.width(), depth.height())?;
        // SceneNet's reader turns "no reading" (0 mm) into NaN: there it means missing, not invalid.
        let stats = DepthStats::of(&depth, self.format == ClipFormat::SceneNet);
        Ok((depth, stats))
    }

    pub fn load_frame(&self, i: usize) -> Result<Frame> {
        Ok(Frame { image: self.load_image(i)?, depth: self.load_depth(i)? })
    }

    fn frame_files(&self, i: usize) -> Result<&FrameFiles> {
        self.files.get(i).ok_or_else(|| {
            DataError::invalid(&self.path, format!("frame index {i} out of range: the clip has {} frames", self.len()))
        })
    }

    /// Files may change between `open` and a load: check again what the header promised.
    fn check_size(&self, path: &Path, width: usize, height: usize) -> Result<()> {
        check_size(path, (width, height), (self.width, self.height))
    }
}

fn check_size(path: &Path, found: (usize, usize), expected: (usize, usize)) -> Result<()> {
    if found == expected {
        Ok(())
    } else {
        Err(DataError::SizeMismatch { path: path.to_path_buf(), found, expected })
    }
}

/// `rgb/` means IISc-VEED, `photo/` means SceneNet RGB-D.
fn detect_format(dir: &Path) -> Result<ClipFormat> {
    let meta = fs::metadata(dir).map_err(|e| DataError::io(dir, "cannot open clip folder", e))?;
    if !meta.is_dir() {
        return Err(DataError::invalid(dir, "not a folder"));
    }
    if dir.join(Layout::IISC_VEED.image_dir).is_dir() {
        Ok(ClipFormat::IiscVeed)
    } else if dir.join(Layout::SCENENET.image_dir).is_dir() {
        Ok(ClipFormat::SceneNet)
    } else {
        Err(DataError::invalid(dir, "not a clip: neither rgb/ (IISc-VEED) nor photo/ (SceneNet RGB-D) found"))
    }
}

fn check_pose_count(dir: &Path, files: &[FrameFiles], poses: usize) -> Result<()> {
    if poses == files.len() {
        return Ok(());
    }
    let (first, last) = (&files[0].image, &files[files.len() - 1].image);
    let problem = format!(
        "{poses} poses (rows) for {} frames ({} .. {}): one row per frame is required",
        files.len(),
        first.display(),
        last.display()
    );
    Err(DataError::invalid(&dir.join(POSES_FILE), problem))
}

/// The smallest frame side ivp accepts: a thinner frame is a strip whose every pixel lies on the
/// border, where warping, the hole search and SSIM's window have nothing to work with. The check
/// comes before the intrinsics', whose complaint about such a frame would miss the point.
pub const MIN_FRAME_SIDE: usize = 4;

/// The most pixels a frame may have (8192 x 8192, above 8K UHD): a header claiming more is refused
/// before anything is decoded, so that no reader allocates for it.
pub const MAX_FRAME_PIXELS: usize = 8192 * 8192;

/// The size shared by every image and depth file, from their headers.
fn common_size(format: ClipFormat, files: &[FrameFiles]) -> Result<(usize, usize)> {
    let depth_size = |path: &Path| match format {
        ClipFormat::IiscVeed => depth_exr_size(path),
        ClipFormat::SceneNet => image_size(path),
    };
    let expected = image_size(&files[0].image)?;
    let (width, height) = expected;
    if width < MIN_FRAME_SIDE || height < MIN_FRAME_SIDE {
        let problem = format!(
            "the frame is {width}x{height} pixels: ivp needs frames of at least {MIN_FRAME_SIDE}x{MIN_FRAME_SIDE}"
        );
        return Err(DataError::invalid(&files[0].image, problem));
    }
    if width.saturating_mul(height) > MAX_FRAME_PIXELS {
        let problem = format!(
            "the header claims {width}x{height} pixels, more than ivp reads ({MAX_FRAME_PIXELS} pixels, 8192x8192)"
        );
        return Err(DataError::invalid(&files[0].image, problem));
    }
    for frame in files {
        check_size(&frame.image, image_size(&frame.image)?, expected)?;
        check_size(&frame.depth, depth_size(&frame.depth)?, expected)?;
    }
    Ok(expected)
}

/// `CameraIntrinsics.csv` if present, else the format's fixed camera, which needs its frame size.
fn clip_intrinsics(dir: &Path, format: ClipFormat, size: (usize, usize)) -> Result<Intrinsics> {
    let file = dir.join(INTRINSICS_FILE);
    if file.exists() {
        let k = read_intrinsics(&file)?;
        check_intrinsics(&k, Some(size)).map_err(|problem| DataError::invalid(&file, problem))?;
        return Ok(k);
    }
    let (camera, valid_size) = format.default_camera();
    if size != valid_size {
        let problem = format!(
            "file missing, and the default {format:?} camera is valid only for {}x{} frames, not {}x{}",
            valid_size.0, valid_size.1, size.0, size.1
        );
        return Err(DataError::invalid(&file, problem));
    }
    Ok(camera)
}
