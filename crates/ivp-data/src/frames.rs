//! Numbered frame files of a clip and the consistency of their numbering.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

use crate::error::{list_paths, DataError, Result};

/// Where a clip format keeps its frames and how it numbers them.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout {
    pub image_dir: &'static str,
    pub image_ext: &'static str,
    pub depth_dir: &'static str,
    pub depth_ext: &'static str,
    /// Difference between consecutive frame numbers.
    pub step: u64,
    /// Zero-padded width of the numbers in file names written by this crate.
    pub digits: usize,
}

impl Layout {
    pub const IISC_VEED: Layout =
        Layout { image_dir: "rgb", image_ext: "png", depth_dir: "depth", depth_ext: "exr", step: 1, digits: 4 };
    pub const SCENENET: Layout =
        Layout { image_dir: "photo", image_ext: "jpg", depth_dir: "depth", depth_ext: "png", step: 25, digits: 0 };

    pub fn image_path(&self, clip: &Path, number: u64) -> PathBuf {
        clip.join(self.image_dir).join(format!("{number:0w$}.{}", self.image_ext, w = self.digits))
    }

    pub fn depth_path(&self, clip: &Path, number: u64) -> PathBuf {
        clip.join(self.depth_dir).join(format!("{number:0w$}.{}", self.depth_ext, w = self.digits))
    }
}

/// The files of one frame.
#[derive(Clone, Debug)]
pub(crate) struct FrameFiles {
    pub number: u64,
    pub image: PathBuf,
    pub depth: PathBuf,
}

/// The frames of a clip in numeric order, after checking that image and depth files pair up and
/// that the numbering has no gap.
pub(crate) fn list_frames(clip: &Path, layout: &Layout) -> Result<Vec<FrameFiles>> {
    let images = numbered_files(clip, &clip.join(layout.image_dir), layout.image_ext)?;
    let depths = numbered_files(clip, &clip.join(layout.depth_dir), layout.depth_ext)?;
    if images.is_empty() && depths.is_empty() {
        let dir = clip.join(layout.image_dir);
        return Err(DataError::frames(clip, format!("no frame files (*.{}) in {}", layout.image_ext, dir.display())));
    }
    check_pairs(clip, layout, &images, &depths)?;
    check_numbering(clip, layout, &images)?;
    let frames = images
        .into_iter()
        .map(|(number, image)| FrameFiles { number, depth: depths[&number].clone(), image })
        .collect();
    Ok(frames)
}

/// Files `<digits>.<ext>` of `dir` by number; other files are ignored (hidden files, notes, ...).
pub(crate) fn numbered_files(clip: &Path, dir: &Path, ext: &str) -> Result<BTreeMap<u64, PathBuf>> {
    let mut files = BTreeMap::new();
    for (number, path) in frame_files_in(dir, ext)? {
        if let Some(other) = files.insert(number, path.clone()) {
            let problem = format!("two files for frame {number}: {} and {}", other.display(), path.display());
            return Err(DataError::frames(clip, problem));
        }
    }
    Ok(files)
}

/// Every `<digits>.<ext>` file of `dir` with its number, in no particular order.
pub(crate) fn frame_files_in(dir: &Path, ext: &str) -> Result<Vec<(u64, PathBuf)>> {
    let entries = fs::read_dir(dir).map_err(|e| DataError::io(dir, "cannot list frame folder", e))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| DataError::io(dir, "cannot list frame folder", e))?.path();
        if let Some(number) = frame_number(&path, ext) {
            files.push((number, path));
        }
    }
    Ok(files)
}

/// The number of a frame file named `<digits>.<ext>` (extension case-insensitive).
fn frame_number(path: &Path, ext: &str) -> Option<u64> {
    let file_ext = path.extension()?.to_str()?;
    let stem = path.file_stem()?.to_str()?;
    let numeric = !stem.is_empty() && stem.bytes().all(|b| b.is_ascii_digit());
    if file_ext.eq_ignore_ascii_case(ext) && numeric {
        stem.parse().ok()
    } else {
        None
    }
}

/// Every image needs a depth map of the same number and vice versa.
fn check_pairs(
    clip: &Path,
    layout: &Layout,
    images: &BTreeMap<u64, PathBuf>,
    depths: &BTreeMap<u64, PathBuf>,
) -> Result<()> {
    let missing_depth: Vec<PathBuf> =
        images.keys().filter(|n| !depths.contains_key(n)).map(|&n| layout.depth_path(clip, n)).collect();
    let missing_image: Vec<PathBuf> =
        depths.keys().filter(|n| !images.contains_key(n)).map(|&n| layout.image_path(clip, n)).collect();
    let mut problems = Vec::new();
    if !missing_depth.is_empty() {
        problems.push(format!("missing depth files {} (their images exist)", list_paths(&missing_depth)));
    }
    if !missing_image.is_empty() {
        problems.push(format!("missing image files {} (their depth maps exist)", list_paths(&missing_image)));
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(DataError::frames(clip, problems.join("; ")))
    }
}

/// Frame numbers must run `first, first + step, ...` without gaps or numbers off that grid.
fn check_numbering(clip: &Path, layout: &Layout, numbers: &BTreeMap<u64, PathBuf>) -> Result<()> {
    let (Some(&first), Some(&last)) = (numbers.keys().next(), numbers.keys().next_back()) else { return Ok(()) };
    let off_grid: Vec<PathBuf> =
        numbers.iter().filter(|(&n, _)| (n - first) % layout.step != 0).map(|(_, p)| p.clone()).collect();
    if !off_grid.is_empty() {
        let problem = format!(
            "frame numbers must step by {} from {first}: unexpected frames {}",
            layout.step,
            list_paths(&off_grid)
        );
        return Err(DataError::frames(clip, problem));
    }
    // Count the gaps before listing any: one stray file numbered 99999999 must not make us build
    // a hundred million paths.
    let expected = ((last - first) / layout.step).saturating_add(1);
    let present = numbers.len() as u64;
    if expected == present {
        return Ok(());
    }
    let missing = expected - present;
    let shown: Vec<u64> =
        (first..=last).step_by(layout.step as usize).filter(|n| !numbers.contains_key(n)).take(4).collect();
    let paths: Vec<PathBuf> =
        shown.iter().flat_map(|&n| [layout.image_path(clip, n), layout.depth_path(clip, n)]).collect();
    let more = if missing > shown.len() as u64 {
        format!(" and {} more frames", missing - shown.len() as u64)
    } else {
        String::new()
    };
    let mut problem = format!("frame numbering has gaps: missing {}{more}", list_paths(&paths));
    if missing > present {
        // More holes than frames: most likely one stray, far-numbered file at either end.
        let keys: Vec<u64> = numbers.keys().copied().collect();
        let n = keys.len();
        let stray = if keys[n - 1] - keys[n - 2] >= keys[1] - keys[0] { last } else { first };
        let _ = write!(
            problem,
            "; {} (frame {stray}) lies far from the other {} frames: remove or renumber it",
            numbers[&stray].display(),
            present - 1
        );
    }
    Err(DataError::frames(clip, problem))
}
