//! Camera paths like a head-mounted display's at 30 fps: mostly sideways drift with a slow turn of
//! the head, both wobbling smoothly.
//!
//! The path is built from per-frame steps rather than from positions, so that the size of every
//! step is controlled directly: a step's length is the base speed times `1 +- 0.3` wobble, and its
//! rotation the base turn rate times `1 +- 0.2` wobble plus smaller pitch and roll terms. Each wobble
//! is a sum of three low-frequency sinusoids (0.15-1.2 Hz) of random phase.

use std::f64::consts::TAU;
use std::ops::RangeInclusive;

use glam::{DMat3, DMat4, DVec3};
use ivp_core::WorldToCamera;
use rand::Rng;

/// Frame rate the per-frame motion is meant for.
pub const FPS: f64 = 30.0;
/// Camera translation per frame at `motion_scale` 1, metres (every step lies in this range).
pub const TRANSLATION_PER_FRAME_M: RangeInclusive<f64> = 0.01..=0.03;
/// Camera rotation per frame at `motion_scale` 1, degrees (every step lies in this range).
pub const ROTATION_PER_FRAME_DEG: RangeInclusive<f64> = 0.2..=0.5;

/// Base step length; with the `1 +- SPEED_WOBBLE` factor every step stays in
/// [`TRANSLATION_PER_FRAME_M`].
const BASE_SPEED_M: RangeInclusive<f64> = 0.0145..=0.022;
const SPEED_WOBBLE: f64 = 0.3;
/// Base turn rate; with the yaw wobble and the pitch and roll terms every step stays in
/// [`ROTATION_PER_FRAME_DEG`] (worst cases 0.224 and 0.47 degrees, see the tests).
const BASE_TURN_DEG: RangeInclusive<f64> = 0.28..=0.37;
const YAW_WOBBLE: f64 = 0.2;
/// Pitch and roll rates relative to the base turn rate.
const PITCH_RATE: f64 = 0.3;
const ROLL_RATE: f64 = 0.2;
/// Deviation of the direction of travel from the camera's initial sideways axis.
const HEADING_OFFSET_DEG: f64 = 25.0;
const HEADING_WOBBLE_DEG: f64 = 20.0;
/// Vertical component of a step relative to its horizontal one (head bob).
const BOB: f64 = 0.25;

/// Where a camera is and where it looks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraState {
    /// World position, metres (world z is up).
    pub position: DVec3,
    /// Heading in radians, about world z, from +y towards +x.
    pub yaw: f64,
    /// Radians above the horizon (negative looks down).
    pub pitch: f64,
    /// Radians about the viewing direction (positive turns the image clockwise).
    pub roll: f64,
}

impl CameraState {
    /// The camera's axes in world space: right, down, forward (OpenCV: x, y, z).
    pub fn axes(&self) -> [DVec3; 3] {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        let forward = DVec3::new(sy * cp, cy * cp, sp);
        let level_right = DVec3::new(cy, -sy, 0.0);
        // right x down = forward for a right-handed camera frame.
        let level_down = forward.cross(level_right);
        let (sr, cr) = self.roll.sin_cos();
        [cr * level_right + sr * level_down, -sr * level_right + cr * level_down, forward]
    }

    pub fn world_to_camera(&self) -> WorldToCamera {
        let [right, down, forward] = self.axes();
        // The inverse of a rigid transform: transposed rotation, rotated and negated translation.
        let rotation = DMat3::from_cols(right, down, forward).transpose();
        let translation = -(rotation * self.position);
        WorldToCamera(DMat4::from_cols(
            rotation.x_axis.extend(0.0),
            rotation.y_axis.extend(0.0),
            rotation.z_axis.extend(0.0),
            translation.extend(1.0),
        ))
    }
}

/// A smooth signal in `[-1, 1]`: three sinusoids of random frequency and phase.
#[derive(Clone, Copy, Debug)]
struct Wobble {
    /// (amplitude, angular frequency per frame, phase); amplitudes sum to 1.
    terms: [(f64, f64, f64); 3],
}

impl Wobble {
    fn random(rng: &mut impl Rng) -> Self {
        let mut terms = [(0.0, 0.0, 0.0); 3];
        for term in &mut terms {
            let hz = rng.random_range(0.15..1.2);
            *term = (rng.random_range(0.2..1.0), TAU * hz / FPS, rng.random_range(0.0..TAU));
        }
        let total: f64 = terms.iter().map(|t| t.0).sum();
        terms.iter_mut().for_each(|t| t.0 /= total);
        Self { terms }
    }

    fn at(&self, frame: f64) -> f64 {
        self.terms.iter().map(|&(amplitude, omega, phase)| amplitude * (omega * frame + phase).sin()).sum()
    }
}

/// A random head-motion path of `frames` camera states starting at `start`; `motion_scale`
/// multiplies every step's translation and rotation.
pub fn head_motion(rng: &mut impl Rng, start: CameraState, frames: usize, motion_scale: f64) -> Vec<CameraState> {
    let speed = rng.random_range(BASE_SPEED_M) * motion_scale;
    let turn = rng.random_range(BASE_TURN_DEG).to_radians() * motion_scale;
    let sideways = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let turn_sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let heading_offset = rng.random_range(-HEADING_OFFSET_DEG..=HEADING_OFFSET_DEG).to_radians();
    let [speed_wobble, heading_wobble, bob_wobble, yaw_wobble, pitch_wobble, roll_wobble] =
        std::array::from_fn(|_| Wobble::random(rng));

    // The direction of travel turns with the wobble but not with the head: people drift sideways
    // along a line while they look around.
    let right = start.axes()[0];
    let level_right = DVec3::new(right.x, right.y, 0.0).normalize_or(DVec3::X);
    let mut states = Vec::with_capacity(frames);
    let mut state = start;
    for n in 0..frames {
        states.push(state);
        // Step n leads from frame n to frame n + 1; sample the wobbles half-way.
        let t = n as f64 + 0.5;
        let heading = heading_offset + HEADING_WOBBLE_DEG.to_radians() * heading_wobble.at(t);
        let (sh, ch) = heading.sin_cos();
        let horizontal =
            DVec3::new(ch * level_right.x - sh * level_right.y, sh * level_right.x + ch * level_right.y, 0.0);
        let direction = (sideways * horizontal + DVec3::new(0.0, 0.0, BOB * bob_wobble.at(t))).normalize();
        state.position += speed * (1.0 + SPEED_WOBBLE * speed_wobble.at(t)) * direction;
        state.yaw += turn * turn_sign * (1.0 + YAW_WOBBLE * yaw_wobble.at(t));
        state.pitch += turn * PITCH_RATE * pitch_wobble.at(t);
        state.roll += turn * ROLL_RATE * roll_wobble.at(t);
    }
    states
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use glam::DVec4;
    use ivp_core::relative_pose;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn camera_axes_follow_opencv() {
        let state = CameraState { position: DVec3::new(1.0, 2.0, 1.5), yaw: 0.0, pitch: 0.0, roll: 0.0 };
        let [right, down, forward] = state.axes();
        assert_eq!((right, down, forward), (DVec3::X, DVec3::NEG_Z, DVec3::Y));
        let e = state.world_to_camera();
        // A point 3 m ahead and 1 m to the right is at camera (1, 0, 3).
        let p = e.0 * DVec4::new(2.0, 5.0, 1.5, 1.0);
        assert!((p.truncate() - DVec3::new(1.0, 0.0, 3.0)).length() < 1e-12);
    }

    /// Translation (metres) and rotation (degrees) of every step of a path.
    pub(crate) fn steps(poses: &[WorldToCamera]) -> Vec<(f64, f64)> {
        poses
            .windows(2)
            .map(|w| {
                let centre = |e: &WorldToCamera| e.camera_to_world().w_axis.truncate();
                let relative = relative_pose(&w[0], &w[1]);
                let trace = relative.x_axis.x + relative.y_axis.y + relative.z_axis.z;
                let angle = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
                ((centre(&w[1]) - centre(&w[0])).length(), angle)
            })
            .collect()
    }

    #[test]
    fn every_step_is_in_range_and_scales_with_motion_scale() {
        for seed in 0..200 {
            let start = CameraState {
                position: DVec3::new(0.0, 0.0, 1.6),
                yaw: 0.3,
                pitch: (-15.0f64 + (seed % 16) as f64).to_radians(),
                roll: 0.02,
            };
            let path = |scale: f64| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let states = head_motion(&mut rng, start, 30, scale);
                steps(&states.iter().map(CameraState::world_to_camera).collect::<Vec<_>>())
            };
            let unit = path(1.0);
            for &(translation, rotation) in &unit {
                assert!(TRANSLATION_PER_FRAME_M.contains(&translation), "seed {seed}: {translation} m");
                assert!(ROTATION_PER_FRAME_DEG.contains(&rotation), "seed {seed}: {rotation} deg");
            }
            let scaled = path(4.0);
            for (&(t1, r1), &(t4, r4)) in unit.iter().zip(&scaled) {
                assert!((t4 / t1 - 4.0).abs() < 1e-9, "translation scales exactly: {t1} {t4}");
                // Euler angles compose slightly non-linearly: the rotation scales almost exactly.
                assert!((r4 / r1 / 4.0 - 1.0).abs() < 0.02, "rotation scales: {r1} {r4}");
            }
        }
    }
}
