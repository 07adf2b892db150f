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

pub mod geometry;
mod layout;
mod render;
pub mod texture;
pub mod trajectory;

#[cfg(test)]
mod tests;

use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use glam::Vec3;
use ivp_core::{Intrinsics, WorldToCamera};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::{write_clip, DataError, Frame, Result};
pub use geometry::{Cylinder, Room, RoomFace, Shape, Sphere, YawedBox};
pub use texture::{Pattern, Texture};
pub use trajectory::CameraState;

/// What random clips look like.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneParams {
    pub width: usize,
    pub height: usize,
    /// Frames per clip.
    pub frames: usize,
    /// Multiplies the camera's translation and rotation per frame (1: a head-mounted display at
    /// 30 fps, about 1-3 cm and 0.2-0.5 degrees; larger for low-frame-rate data like SceneNet).
    pub motion_scale: f64,
    /// Horizontal field of view in degrees, drawn per clip.
    pub hfov_deg: RangeInclusive<f64>,
    /// Number of objects, drawn per clip (fewer if some find no free place).
    pub objects: RangeInclusive<usize>,
    /// How many of the objects stand close to the camera, at [`SceneParams::near_distance`].
    pub near_objects: usize,
    /// Distance in metres from the camera's start to the nearest point of a near object.
    pub near_distance: RangeInclusive<f64>,
    /// Distance in metres from the camera's start to the far wall or backdrop, along its view.
    pub background_distance: RangeInclusive<f64>,
    /// Probability of open ground with a distant backdrop instead of a room.
    pub open_ground_probability: f64,
}

impl Default for SceneParams {
    fn default() -> Self {
        Self {
            width: 320,
            height: 240,
            frames: 12,
            motion_scale: 1.0,
            hfov_deg: 50.0..=75.0,
            objects: 6..=12,
            near_objects: 3,
            near_distance: 0.8..=1.5,
            background_distance: 4.0..=10.0,
            open_ground_probability: 0.2,
        }
    }
}

/// The one light of a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Unit vector pointing towards the light.
    pub direction: Vec3,
    /// Brightness of a surface facing the light, on top of `ambient`.
    pub intensity: f32,
    /// Brightness of every surface.
    pub ambient: f32,
}

/// A solid object with its texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneObject {
    pub shape: Shape,
    pub texture: Texture,
}

/// A static scene: the room around everything, its objects and the light.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub room: Room,
    /// One texture per face, indexed by `RoomFace as usize`.
    pub room_textures: [Texture; 6],
    pub objects: Vec<SceneObject>,
    pub light: Light,
}

/// The camera of a clip: intrinsics and one world-to-camera pose per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    pub intrinsics: Intrinsics,
    pub poses: Vec<WorldToCamera>,
}

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
