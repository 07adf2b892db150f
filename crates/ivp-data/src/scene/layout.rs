//! Random scenes laid out around a random camera path.
//!
//! The path comes first, so that the room can be built around it and the objects kept clear of
//! it. Objects are placed where the camera looks at the start: `near_objects` of them close by
//! (they make the largest disocclusions), the rest spread over distance slots up to the far wall,
//! so that depths differ clearly. Each object is lifted or lowered into the vertical band that the
//! camera sees at its distance: an object on the floor a metre away would be below the image.

use std::f64::consts::PI;
use std::ops::RangeInclusive;

use glam::{Affine2, DVec2, DVec3, Vec2, Vec3};
use ivp_core::Intrinsics;
use rand::Rng;

use super::description::{CameraPath, Light, Scene, SceneObject, SceneParams};
use super::geometry::{Cylinder, Room, RoomFace, Shape, Sphere, YawedBox};
use super::texture::{hsv_to_rgb, Pattern, Texture};
use super::trajectory::{head_motion, CameraState};

const EYE_HEIGHT_M: RangeInclusive<f64> = 1.3..=1.8;
/// The start view turns at most this far from the room's long axis (+y).
const START_YAW_DEG: f64 = 20.0;
const START_PITCH_DEG: RangeInclusive<f64> = -12.0..=-2.0;
const START_ROLL_DEG: f64 = 2.0;
/// The camera path keeps at least this far from the walls, floor and ceiling.
const WALL_CLEARANCE_M: f64 = 0.6;
/// The camera path keeps at least this far (horizontally) from an object's footprint.
const OBJECT_CLEARANCE_M: f64 = 0.5;
/// Objects keep this far from the walls.
const OBJECT_WALL_GAP_M: f64 = 0.05;
/// Objects stop this far in front of the far wall.
const FAR_WALL_GAP_M: f64 = 0.5;
/// Tries to find a free place for one object before giving it up.
const PLACEMENT_ATTEMPTS: usize = 30;
/// Only the central part of the visible band counts as "in view" for vertical placement.
const BAND_MARGIN: f64 = 0.2;
/// A near object is at most this share (drawn per object) of the central band's height.
const NEAR_OBJECT_BAND_SHARE: RangeInclusive<f64> = 0.5..=1.0;
/// Near objects go into the central part of the view of this share of its width.
const NEAR_VIEW_SHARE: f64 = 0.8;
/// A near object is not placed where the room leaves less of the band than this.
const MIN_NEAR_OBJECT_HEIGHT_M: f64 = 0.1;
/// How much finer than its own sizes a fine texture's pattern is (`fine_texture_probability`).
const FINE_TEXTURE_FACTOR: RangeInclusive<f32> = 2.0..=4.0;

/// Room proportions: free space beside and behind the camera path, height.
struct RoomStyle {
    side_space_m: RangeInclusive<f64>,
    back_space_m: RangeInclusive<f64>,
    height_m: RangeInclusive<f64>,
}

const INDOOR: RoomStyle = RoomStyle { side_space_m: 2.0..=5.0, back_space_m: 0.5..=2.5, height_m: 2.6..=4.0 };
/// Open ground: a large box whose walls are a distant backdrop and whose ceiling is a sky.
const OPEN_GROUND: RoomStyle = RoomStyle { side_space_m: 5.0..=12.0, back_space_m: 2.0..=6.0, height_m: 8.0..=15.0 };

impl Scene {
    /// A random scene with the camera path it was laid out around (objects keep clear of the path,
    /// the path stays inside the room).
    pub fn random(rng: &mut impl Rng, params: &SceneParams) -> (Scene, CameraPath) {
        let hfov = rng.random_range(params.hfov_deg.clone()).to_radians();
        let intrinsics = centred_intrinsics(hfov, params.width, params.height);
        let vfov = 2.0 * (params.height as f64 / 2.0 / intrinsics.fy).atan();
        let start = CameraState {
            position: DVec3::new(0.0, 0.0, rng.random_range(EYE_HEIGHT_M)),
            yaw: rng.random_range(-START_YAW_DEG..=START_YAW_DEG).to_radians(),
            pitch: rng.random_range(START_PITCH_DEG).to_radians(),
            roll: rng.random_range(-START_ROLL_DEG..=START_ROLL_DEG).to_radians(),
        };
        let states = head_motion(rng, start, params.frames, params.motion_scale);
        // The start alone when the clip has no frames, so that the room is still well defined.
        let path: Vec<DVec3> =
            states.iter().map(|s| s.position).chain(states.is_empty().then_some(start.position)).collect();
        let open_ground = rng.random_bool(params.open_ground_probability);
        let style = if open_ground { &OPEN_GROUND } else { &INDOOR };
        let background_distance = rng.random_range(params.background_distance.clone());
        let room = room_around(rng, style, &start, &path, background_distance);
        let mut room_textures: [Texture; 6] = std::array::from_fn(|_| random_texture(rng, params));
        if open_ground {
            room_textures[RoomFace::Ceiling as usize] = sky(rng);
        }
        let light = random_light(rng);
        let view = StartView { camera: start, hfov, vfov };
        let objects = place_objects(rng, params, &room, &path, &view);
        let poses = states.iter().map(CameraState::world_to_camera).collect();
        (Scene { room, room_textures, objects, light }, CameraPath { intrinsics, poses })
    }
}

/// A centred pinhole camera with square pixels and horizontal field of view `hfov` (radians).
fn centred_intrinsics(hfov: f64, width: usize, height: usize) -> Intrinsics {
    let f = width as f64 / 2.0 / (hfov / 2.0).tan();
    Intrinsics::new(f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0)
}

/// A room that holds the path with clearance; its far wall (`+y`) lies `background_distance`
/// ahead of the start view.
fn room_around(
    rng: &mut impl Rng,
    style: &RoomStyle,
    start: &CameraState,
    path: &[DVec3],
    background_distance: f64,
) -> Room {
    let lo = path.iter().fold(DVec3::INFINITY, |a, &p| a.min(p));
    let hi = path.iter().fold(DVec3::NEG_INFINITY, |a, &p| a.max(p));
    let far_y = (start.position.y + background_distance * start.yaw.cos()).max(hi.y + WALL_CLEARANCE_M);
    let min = DVec3::new(
        lo.x - space(rng, &style.side_space_m),
        lo.y - space(rng, &style.back_space_m),
        (lo.z - WALL_CLEARANCE_M).min(0.0),
    );
    let max = DVec3::new(
        hi.x + space(rng, &style.side_space_m),
        far_y,
        rng.random_range(style.height_m.clone()).max(hi.z + WALL_CLEARANCE_M),
    );
    Room { min: min.as_vec3(), max: max.as_vec3() }
}

/// Free space beside or behind the path, at least the wall clearance.
fn space(rng: &mut impl Rng, range: &RangeInclusive<f64>) -> f64 {
    rng.random_range(range.clone()).max(WALL_CLEARANCE_M)
}

/// A random texture, its pattern made finer with `params.fine_texture_probability`. The draw is
/// skipped at probability 0 so that the default scenes stay those of earlier versions.
fn random_texture(rng: &mut impl Rng, params: &SceneParams) -> Texture {
    let mut texture = Texture::random(rng);
    if params.fine_texture_probability > 0.0 && rng.random_bool(params.fine_texture_probability) {
        let finer = rng.random_range(FINE_TEXTURE_FACTOR);
        texture.placement = Affine2::from_scale(Vec2::splat(finer)) * texture.placement;
    }
    texture
}

/// A pale blue, cloudy texture for the ceiling of open ground.
fn sky(rng: &mut impl Rng) -> Texture {
    let mut texture = Texture::random(rng);
    let hue = rng.random_range(0.55..0.62);
    texture.pattern = Pattern::Noise { scale: rng.random_range(1.5..4.0) };
    texture.palette = [
        hsv_to_rgb(hue, rng.random_range(0.3..0.6), rng.random_range(0.75..0.95)),
        hsv_to_rgb(hue, 0.05, 0.97),
        hsv_to_rgb(hue, rng.random_range(0.1..0.3), 0.9),
        Vec3::ONE,
    ];
    texture.grain = 0.0;
    texture
}

fn random_light(rng: &mut impl Rng) -> Light {
    let azimuth: f32 = rng.random_range(0.0..2.0 * std::f32::consts::PI);
    let elevation: f32 = rng.random_range(30f32..75.0).to_radians();
    let direction = Vec3::new(elevation.cos() * azimuth.sin(), elevation.cos() * azimuth.cos(), elevation.sin());
    Light { direction, intensity: rng.random_range(0.5..0.7), ambient: rng.random_range(0.25..0.4) }
}

/// What the camera sees at the start: objects are placed there.
struct StartView {
    camera: CameraState,
    hfov: f64,
    vfov: f64,
}

impl StartView {
    /// The heights `(lo, hi)` that the middle of the image shows at horizontal distance `d`.
    fn visible_band(&self, d: f64) -> (f64, f64) {
        let z = self.camera.position.z;
        let lo = z + d * (self.camera.pitch - self.vfov / 2.0).tan();
        let hi = z + d * (self.camera.pitch + self.vfov / 2.0).tan();
        (lo + BAND_MARGIN * (hi - lo), hi - BAND_MARGIN * (hi - lo))
    }
}

fn place_objects(
    rng: &mut impl Rng,
    params: &SceneParams,
    room: &Room,
    path: &[DVec3],
    view: &StartView,
) -> Vec<SceneObject> {
    let count = rng.random_range(params.objects.clone());
    let near_count = params.near_objects.min(count);
    // Horizontal distance from the start to the far wall along the start view.
    let far_wall = (room.max.y as f64 - view.camera.position.y) / view.camera.yaw.cos();
    let near_end = *params.near_distance.end();
    let far_end = (far_wall - FAR_WALL_GAP_M).max(near_end + 0.5);
    let slots = count - near_count;
    let slot_width = (far_end - near_end) / slots.max(1) as f64;
    // Near objects in separate sectors of the central 80% of the view, so that they do not hide
    // each other and each uncovers background; the others anywhere in view or just beside it (the
    // camera turns).
    let near_sector = NEAR_VIEW_SHARE * view.hfov / near_count.max(1) as f64;
    let wide = 0.5 * view.hfov + 5f64.to_radians();
    let mut objects = Vec::with_capacity(count);
    for i in 0..count {
        let slot = if i < near_count {
            let first = -0.5 * NEAR_VIEW_SHARE * view.hfov + i as f64 * near_sector;
            Slot { distance: params.near_distance.clone(), azimuth: first..=first + near_sector, near: true }
        } else {
            let first = near_end + (i - near_count) as f64 * slot_width;
            Slot { distance: first..=first + slot_width, azimuth: -wide..=wide, near: false }
        };
        let placed = (0..PLACEMENT_ATTEMPTS).find_map(|_| try_place(rng, params, room, path, view, &slot));
        objects.extend(placed);
    }
    objects
}

/// The kinds of object, with the size ranges they are drawn from.
#[derive(Clone, Copy, Debug)]
enum Kind {
    Box,
    Sphere,
    Cylinder,
    /// Floor to ceiling, round or square.
    Column,
    /// Floor to ceiling, a few centimetres thick.
    Pole,
}

impl Kind {
    /// A random kind; `free_standing` excludes the floor-to-ceiling kinds.
    fn random(rng: &mut impl Rng, free_standing: bool) -> Self {
        match rng.random_range(0..if free_standing { 14 } else { 20 }) {
            0..6 => Kind::Box,
            6..10 => Kind::Sphere,
            10..14 => Kind::Cylinder,
            14..17 => Kind::Column,
            _ => Kind::Pole,
        }
    }

    /// A column or a pole, in the proportions of [`Kind::random`].
    fn random_floor_to_ceiling(rng: &mut impl Rng) -> Self {
        if rng.random_range(0..6) < 3 {
            Kind::Column
        } else {
            Kind::Pole
        }
    }
}

/// Where an object may go.
struct Slot {
    /// Horizontal distance from the start to the object's nearest side, metres.
    distance: RangeInclusive<f64>,
    /// Direction from the start, radians from the start view (positive to the right).
    azimuth: RangeInclusive<f64>,
    /// Near objects are free-standing and float inside the view.
    near: bool,
}

/// One attempt to place an object of a random kind in `slot`; `None` if the place is not free.
fn try_place(
    rng: &mut impl Rng,
    params: &SceneParams,
    room: &Room,
    path: &[DVec3],
    view: &StartView,
    slot: &Slot,
) -> Option<SceneObject> {
    let near = slot.near;
    // A near object spans the image unless it is small and floats inside the view: much of the
    // background it uncovers then reaches the image border, which makes it a new region, not a
    // disocclusion (ALGORITHMS.md §4.1). So near objects are mostly free-standing and shrunk to
    // fit the view; a near column (`near_column_probability`) spans it on purpose. The draw is
    // skipped at probability 0 so that the default scenes stay those of earlier versions.
    let near_column = near && params.near_column_probability > 0.0 && rng.random_bool(params.near_column_probability);
    let kind = if near_column { Kind::random_floor_to_ceiling(rng) } else { Kind::random(rng, near) };
    let (floor, ceiling) = (room.min.z as f64, room.max.z as f64);
    // Horizontal half-extents (for boxes) or radius, and height (None: floor to ceiling).
    let (half_x, half_y, height, round) = match kind {
        Kind::Box => {
            (rng.random_range(0.15..0.6), rng.random_range(0.15..0.6), Some(rng.random_range(0.3..1.4)), false)
        }
        Kind::Sphere => {
            let r = rng.random_range(0.15..0.55);
            (r, r, Some(2.0 * r), true)
        }
        Kind::Cylinder => {
            let r = rng.random_range(0.12..0.45);
            (r, r, Some(rng.random_range(0.4..2.0)), true)
        }
        Kind::Column if rng.random_bool(0.5) => {
            let r = rng.random_range(0.1..0.35);
            (r, r, None, true)
        }
        Kind::Column => (rng.random_range(0.1..0.3), rng.random_range(0.1..0.3), None, false),
        Kind::Pole => {
            let r = rng.random_range(0.015..0.06);
            (r, r, None, true)
        }
    };
    let surface_distance = rng.random_range(slot.distance.clone());
    let mut size = DVec3::new(half_x, half_y, height.unwrap_or(ceiling - floor));
    // The band seen at a near object's near side (the narrowest), clipped to the room.
    let (near_lo, near_hi) = view.visible_band(surface_distance);
    let (near_lo, near_hi) = (near_lo.max(floor), near_hi.min(ceiling));
    if near && !near_column {
        if near_hi - near_lo < MIN_NEAR_OBJECT_HEIGHT_M {
            return None;
        }
        let share = rng.random_range(NEAR_OBJECT_BAND_SHARE);
        size *= (share * (near_hi - near_lo) / size.z).min(1.0);
    }
    let footprint = if round { size.x } else { f64::hypot(size.x, size.y) };
    let azimuth = view.camera.yaw + rng.random_range(slot.azimuth.clone());
    let centre_distance = surface_distance + footprint;
    let start = view.camera.position.truncate();
    let centre = start + centre_distance * DVec2::new(azimuth.sin(), azimuth.cos());

    let gap = footprint + OBJECT_WALL_GAP_M;
    let inside = centre.x - gap > room.min.x as f64
        && centre.x + gap < room.max.x as f64
        && centre.y - gap > room.min.y as f64
        && centre.y + gap < room.max.y as f64;
    let clear = path.iter().all(|p| p.truncate().distance(centre) >= footprint + OBJECT_CLEARANCE_M);
    if !inside || !clear {
        return None;
    }

    let bottom = match height {
        None => floor,
        Some(_) if near => rng.random_range(near_lo..=(near_hi - size.z).max(near_lo)),
        Some(_) => vertical_place(rng, view.visible_band(centre_distance), size.z, floor, ceiling),
    };
    let (half_x, half_y, height) = (size.x, size.y, size.z);
    let yaw = rng.random_range(0.0..PI);
    let shape = match kind {
        Kind::Sphere => Shape::Sphere(Sphere {
            centre: DVec3::new(centre.x, centre.y, bottom + half_x).as_vec3(),
            radius: half_x as f32,
        }),
        Kind::Box | Kind::Column if !round => Shape::Box(YawedBox::new(
            DVec3::new(centre.x, centre.y, bottom + height / 2.0).as_vec3(),
            DVec3::new(half_x, half_y, height / 2.0).as_vec3(),
            yaw as f32,
        )),
        _ => Shape::Cylinder(Cylinder {
            base: DVec3::new(centre.x, centre.y, bottom).as_vec3(),
            radius: half_x as f32,
            height: height as f32,
        }),
    };
    Some(SceneObject { shape, texture: random_texture(rng, params) })
}

/// The bottom height of an object of height `h`: on the floor when it is then in view (mostly),
/// else floating with its middle in the visible band `(lo, hi)`.
fn vertical_place(rng: &mut impl Rng, (lo, hi): (f64, f64), h: f64, floor: f64, ceiling: f64) -> f64 {
    let on_floor_visible = floor + h >= lo;
    if on_floor_visible && rng.random_bool(0.65) {
        return floor;
    }
    let lowest = (lo - h / 2.0).max(floor);
    let highest = (hi - h / 2.0).min(ceiling - h);
    if lowest < highest {
        rng.random_range(lowest..highest)
    } else {
        floor
    }
}
