//! Writing clips in the IISc-VEED layout.

use std::collections::BTreeSet;
use std::fs;
use std::path::Path;

use ivp_core::{Intrinsics, WorldToCamera};

use crate::clip::Frame;
use crate::csv::{check_intrinsics, check_pose, write_intrinsics, write_poses, INTRINSICS_FILE, POSES_FILE};
use crate::error::{DataError, Result};
use crate::frames::{frame_files_in, Layout};
use crate::io::{write_depth_exr, write_rgb_png};

/// Writes a clip in the IISc-VEED layout: `rgb/NNNN.png` (8-bit), `depth/NNNN.exr` (f32 `Y`),
/// `TransformationMatrices.csv` and, when given, `CameraIntrinsics.csv`. Without intrinsics the
/// frames must be 1920x1080 (IISc-VEED's fixed camera), else the clip could not be opened.
///
/// The output is byte-deterministic. Frame files of an earlier clip in `dir` that are not part of
/// this one, and a stale `CameraIntrinsics.csv` when `intrinsics` is `None`, are removed so that
/// `dir` holds exactly the clip described.
pub fn write_clip(
    dir: impl AsRef<Path>,
    frames: &[Frame],
    poses: &[WorldToCamera],
    intrinsics: Option<&Intrinsics>,
) -> Result<()> {
    let dir = dir.as_ref();
    check_clip_arguments(dir, frames, poses, intrinsics)?;
    let layout = Layout::IISC_VEED;
    for sub in [layout.image_dir, layout.depth_dir] {
        let sub = dir.join(sub);
        fs::create_dir_all(&sub).map_err(|e| DataError::io(&sub, "cannot create folder", e))?;
    }
    for (n, frame) in frames.iter().enumerate() {
        write_rgb_png(layout.image_path(dir, n as u64), &frame.image)?;
        write_depth_exr(layout.depth_path(dir, n as u64), &frame.depth)?;
    }
    remove_stale_frames(dir, &layout, frames.len())?;
    write_poses(&dir.join(POSES_FILE), poses)?;
    let intrinsics_file = dir.join(INTRINSICS_FILE);
    match intrinsics {
        Some(k) => write_intrinsics(&intrinsics_file, k)?,
        None if intrinsics_file.exists() => {
            fs::remove_file(&intrinsics_file).map_err(|e| DataError::io(&intrinsics_file, "cannot remove", e))?
        }
        None => {}
    }
    Ok(())
}

/// Refuses, before writing anything, what [`crate::Clip::open`] would refuse afterwards.
fn check_clip_arguments(
    dir: &Path,
    frames: &[Frame],
    poses: &[WorldToCamera],
    intrinsics: Option<&Intrinsics>,
) -> Result<()> {
    let Some(first) = frames.first() else { return Err(DataError::invalid(dir, "cannot write a clip without frames")) };
    if poses.len() != frames.len() {
        return Err(DataError::invalid(dir, format!("{} poses given for {} frames", poses.len(), frames.len())));
    }
    let size = (first.image.width(), first.image.height());
    for (n, (frame, pose)) in frames.iter().zip(poses).enumerate() {
        for (what, found) in [
            ("image", (frame.image.width(), frame.image.height())),
            ("depth", (frame.depth.width(), frame.depth.height())),
        ] {
            if found != size {
                let problem =
                    format!("frame {n}: {what} is {}x{}, frame 0's image is {}x{}", found.0, found.1, size.0, size.1);
                return Err(DataError::invalid(dir, problem));
            }
        }
        check_pose(pose).map_err(|p| DataError::invalid(dir, format!("frame {n}: {p}")))?;
    }
    match intrinsics {
        Some(k) => check_intrinsics(k, Some(size)).map_err(|p| DataError::invalid(dir, p)),
        None if size != (1920, 1080) => Err(DataError::invalid(
            dir,
            format!(
                "no intrinsics given for {}x{} frames: the default IISc-VEED camera needs 1920x1080",
                size.0, size.1
            ),
        )),
        None => Ok(()),
    }
}

/// Deletes `rgb/`/`depth/` frame files numbered `count` or above, or otherwise not written now.
fn remove_stale_frames(dir: &Path, layout: &Layout, count: usize) -> Result<()> {
    let written: BTreeSet<_> =
        (0..count as u64).flat_map(|n| [layout.image_path(dir, n), layout.depth_path(dir, n)]).collect();
    for (sub, ext) in [(layout.image_dir, layout.image_ext), (layout.depth_dir, layout.depth_ext)] {
        for (_, path) in frame_files_in(&dir.join(sub), ext)? {
            if !written.contains(&path) {
                fs::remove_file(&path).map_err(|e| DataError::io(&path, "cannot remove stale frame", e))?;
            }
        }
    }
    Ok(())
}
