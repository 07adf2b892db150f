//! Procedural scenes rendered on the fly: training clips with exact depth and poses, as many as
//! wanted, with no renderer outside this crate.
//!
//! A scene holds only what disocclusions need: a closed room (or open ground closed by a distant
//! backdrop, which is the same box made large), objects at clearly different depths in front of the
//! camera, textures that make infilling non-trivial, and Lambert shading with one directional light
//! plus ambient (view-independent, so a warp of a frame matches the next frame up to resampling).
//! The camera moves like a head-mounted display at 30 fps (see [`trajectory`]).
//!
//! - [`render_clip`]: one clip from a seed, fully determined by `(seed, params)`.
//! - [`generate_dataset`]: many clips written to disk in the clip layout of ALGORITHMS.md §3.
//! - [`Scene::random`] and [`Scene::render`] for finer control; [`Scene`] can be built by hand.
//!
//! World axes: metres, z up, floor at z = 0 (cameras use OpenCV axes, see [`ivp_core::geometry::camera`]).

mod description;
pub mod geometry;
mod layout;
mod render;
pub mod texture;
pub mod trajectory;

#[cfg(test)]
mod tests;

use std::path::{Path, PathBuf};

use ivp_core::{Intrinsics, WorldToCamera};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::{write_clip, DataError, Frame, Result};
pub use description::{check_probability, CameraPath, Light, Scene, SceneObject, SceneParams};
pub use geometry::{Cylinder, Room, RoomFace, Shape, Sphere, YawedBox};
pub use texture::{Pattern, Texture};
pub use trajectory::CameraState;

/// A rendered clip in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct SyntheticClip {
    pub frames: Vec<Frame>,
    pub poses: Vec<WorldToCamera>,
    pub intrinsics: Intrinsics,
}

/// Renders the clip of `seed`: a random scene and camera path, every frame rendered. The result
/// depends on `(seed, params)` only, not on the number of threads.
pub fn render_clip(seed: u64, params: &SceneParams) -> SyntheticClip {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (scene, camera) = Scene::random(&mut rng, params);
    let frames = camera.poses.iter().map(|pose| scene.render(pose, &camera.intrinsics, params.width, params.height));
    SyntheticClip { frames: frames.collect(), poses: camera.poses, intrinsics: camera.intrinsics }
}

/// The seed of clip `index` of a dataset generated from `seed`.
pub fn clip_seed(seed: u64, index: usize) -> u64 {
    splitmix64(splitmix64(seed) ^ (index as u64))
}

/// Writes `clips` clips to `out/clip_0000`, `out/clip_0001`, ... (clip `i` rendered from
/// [`clip_seed`]`(seed, i)`), in parallel; `on_clip_done(i)` is called as each clip is written, in
/// any order. Returns the clip folders in index order. The files are byte-identical from run to run.
pub fn generate_dataset(
    out: &Path,
    clips: usize,
    seed: u64,
    params: &SceneParams,
    on_clip_done: impl Fn(usize) + Sync,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out).map_err(|e| DataError::io(out, "cannot create folder", e))?;
    (0..clips)
        .into_par_iter()
        .map(|i| {
            let dir = out.join(format!("clip_{i:04}"));
            let clip = render_clip(clip_seed(seed, i), params);
            write_clip(&dir, &clip.frames, &clip.poses, Some(&clip.intrinsics))?;
            on_clip_done(i);
            Ok(dir)
        })
        .collect()
}

/// SplitMix64's output function: turns nearby seeds into unrelated ones.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}
