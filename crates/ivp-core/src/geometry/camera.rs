//! Pinhole intrinsics and world-to-camera extrinsics (OpenCV axes: x right, y down, z forward).

use glam::{DMat4, DVec2, DVec3, DVec4};

/// Pinhole intrinsics in pixels; integer pixel coordinates are pixel centres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self { fx, fy, cx, cy }
    }

    /// IISc-VEED's fixed camera for 1920x1080 frames (ALGORITHMS.md §3).
    pub fn iisc_veed_default() -> Self {
        Self::new(2100.0, 2100.0, 960.0, 540.0)
    }

    /// SceneNet RGB-D's camera for 320x240 frames (ALGORITHMS.md §3).
    pub fn scenenet_default() -> Self {
        Self::new(160.0 / 30f64.to_radians().tan(), 120.0 / 22.5f64.to_radians().tan(), 160.0, 120.0)
    }

    /// The camera-space point at planar depth `z` seen through pixel `(u, v)`.
    #[inline]
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> DVec3 {
        DVec3::new((u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z)
    }

    /// The pixel of a camera-space point; `None` when it is not in front of the camera.
    #[inline]
    pub fn project(&self, p: DVec3) -> Option<DVec2> {
        if p.z <= 0.0 || !p.is_finite() {
            return None;
        }
        Some(DVec2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// `|K^-1 [u, v, 1]|`: ray length divided by planar depth at pixel `(u, v)`.
    #[inline]
    pub fn ray_length_per_depth(&self, u: f64, v: f64) -> f64 {
        let x = (u - self.cx) / self.fx;
        let y = (v - self.cy) / self.fy;
        (x * x + y * y + 1.0).sqrt()
    }

    /// The 3x3 matrix as rows.
    pub fn matrix(&self) -> [[f64; 3]; 3] {
        [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]]
    }
}

/// A 4x4 world-to-camera transform: `X_cam = E * [X_world, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldToCamera(pub DMat4);

impl WorldToCamera {
    /// From 16 row-major numbers, as one row of `TransformationMatrices.csv`.
    pub fn from_row_major(m: [f64; 16]) -> Self {
        Self(DMat4::from_cols_array(&m).transpose())
    }

    pub fn to_row_major(&self) -> [f64; 16] {
        self.0.transpose().to_cols_array()
    }

    pub fn camera_to_world(&self) -> DMat4 {
        self.0.inverse()
    }
}

/// The transform taking camera-space points of frame `from` to camera-space points of frame `to`:
/// `E_to * inverse(E_from)`.
pub fn relative_pose(from: &WorldToCamera, to: &WorldToCamera) -> DMat4 {
    to.0 * from.0.inverse()
}

/// Applies a 4x4 rigid transform to a point.
#[inline]
pub fn transform_point(t: &DMat4, p: DVec3) -> DVec3 {
    let q = *t * DVec4::new(p.x, p.y, p.z, 1.0);
    DVec3::new(q.x, q.y, q.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn row_major_round_trip_keeps_translation_in_last_column() {
        let m = [1.0, 0.0, 0.0, 5.0, 0.0, 1.0, 0.0, 6.0, 0.0, 0.0, 1.0, 7.0, 0.0, 0.0, 0.0, 1.0];
        let e = WorldToCamera::from_row_major(m);
        assert_eq!(e.0.w_axis.truncate(), DVec3::new(5.0, 6.0, 7.0));
        assert_eq!(e.to_row_major(), m);
    }

    #[test]
    fn unproject_then_project_is_identity() {
        let k = Intrinsics::new(300.0, 280.0, 159.5, 119.5);
        let p = k.unproject(12.25, 200.5, 3.5);
        let q = k.project(p).unwrap();
        assert!((q.x - 12.25).abs() < 1e-12 && (q.y - 200.5).abs() < 1e-12);
        assert!(k.project(DVec3::new(0.0, 0.0, -1.0)).is_none());
    }
}
