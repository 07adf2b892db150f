//! What a scene is: the parameters random scenes are drawn from, the scene (room, objects, light)
//! and the camera's path. `layout.rs` draws them and `render.rs` renders them; `mod.rs` composes
//! the two into clips.

use std::ops::RangeInclusive;

use glam::Vec3;
use ivp_core::{Intrinsics, WorldToCamera};

use super::geometry::{Room, Shape};
use super::texture::Texture;

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
    /// Probability that a near object is a floor-to-ceiling column or pole instead of a
    /// free-standing object shrunk into the view. Such an object spans the image, so the slivers
    /// it uncovers run from border to border, as beside the columns of the Blender clips.
    pub near_column_probability: f64,
    /// Probability that a texture's pattern is drawn 2 to 4 times finer than the patterns'
    /// own sizes. The Blender clips' surfaces carry finer detail than the default patterns (twice
    /// the mean horizontal gradient at 320x240), and a sliver between fine patterns is where a
    /// vector a pixel too long costs most.
    pub fine_texture_probability: f64,
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
            near_column_probability: 0.0,
            fine_texture_probability: 0.0,
            background_distance: 4.0..=10.0,
            open_ground_probability: 0.2,
        }
    }
}

/// Whether `p` can be one of the probabilities of [`SceneParams`]; the error says why not (without
/// the field's name, which callers know under their own).
pub fn check_probability(p: f64) -> Result<(), String> {
    if (0.0..=1.0).contains(&p) {
        Ok(())
    } else {
        Err(format!("must be a probability in [0, 1], got {p}"))
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
