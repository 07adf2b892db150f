//! Clip formats on disk and datasets of clips (ALGORITHMS.md §3).
//!
//! - [`Clip::open`] reads the IISc-VEED layout (`rgb/NNNN.png`, `depth/NNNN.exr`) and the SceneNet
//!   RGB-D layout (`photo/<n>.jpg`, `depth/<n>.png`), both with `TransformationMatrices.csv`;
//!   frames load lazily, in planar depth whatever the format.
//! - [`write_clip`] writes the IISc-VEED layout, byte-deterministically.
//! - [`find_clips`] lists the clips of a dataset folder.
//! - [`read_rgb`], [`write_rgb_png`], [`write_gray_png`], [`read_depth_exr`], [`write_depth_exr`]:
//!   single files; all writes are atomic (temporary file + rename).
//! - [`samples`]: training samples and batches, made deterministically in the background.
//! - [`scene`]: procedural scenes rendered on the fly ([`render_clip`], [`generate_dataset`]).
//!
//! Every error is a [`DataError`] whose message names the file and the problem.

mod clip;
mod csv;
mod depth;
mod discover;
mod error;
mod frames;
mod io;
pub mod samples;
pub mod scene;
mod scenenet;
mod write;

#[cfg(test)]
mod tests;

pub use clip::{Clip, ClipFormat, Frame};
pub use csv::{
    read_intrinsics, read_poses, write_intrinsics, write_poses, BOTTOM_ROW_TOLERANCE, FOCAL_RANGE_IN_WIDTHS,
    INTRINSICS_FILE, MAX_TRANSLATION, POSES_FILE, PRINCIPAL_POINT_SLACK, ROTATION_TOLERANCE,
};
pub use depth::{DepthStats, MAX_PLAUSIBLE_DEPTH, MIN_PLAUSIBLE_DEPTH, SUSPICIOUS_DEPTH_SHARE};
pub use discover::find_clips;
pub use error::{DataError, Result};
pub use io::{
    pick_depth_channel, read_depth_exr, read_rgb, write_atomically, write_depth_exr, write_durably, write_gray_png,
    write_rgb_png, DEPTH_CHANNELS, WRITTEN_DEPTH_CHANNEL,
};
pub use samples::{Batch, Sample, SampleConfig, SampleGenerator, SampleStream, StreamOptions};
pub use scene::{check_probability, generate_dataset, render_clip, Scene, SceneParams, SyntheticClip};
pub use scenenet::{ray_mm_to_planar, read_scenenet_depth, SCENENET_FRAME_STEP};
pub use write::write_clip;
