//! Fixtures shared by the unit tests: a box in front of a wall seen by a camera that slides
//! along x (every frame rendered analytically, so warps of it can be checked against the true
//! frames), and small hand-drawn masks and images.

use glam::{DMat4, DVec3};

use crate::geometry::{relative_pose, warp_forward, FrameView, Warp};
use crate::geometry::{DepthMap, HoleMask, Image, Intrinsics, PixelClass, RgbImage, WorldToCamera};
use crate::infill::InfillContext;

pub const WIDTH: usize = 64;
pub const HEIGHT: usize = 48;
pub const WALL_Z: f64 = 10.0;
pub const BOX_Z: f64 = 2.0;
pub const BOX_COLOUR: [f32; 3] = [1.0, 0.0, 0.0];
/// World x range of the box: columns 20..30 when the camera is at x = 0.
const BOX_X: (f64, f64) = (-0.235, -0.045);
const BOX_ROWS: std::ops::RangeInclusive<usize> = 10..=37;

pub fn intrinsics() -> Intrinsics {
    Intrinsics::new(100.0, 100.0, 31.5, 23.5)
}

/// Stripes along rows only, far from the box colour: a horizontal shift matches exactly.
pub fn wall_colour(v: usize) -> [f32; 3] {
    let g = ((v * v * 7 + 3 * v) % 11) as f32 / 10.0;
    [0.0, g, 1.0]
}

/// Image, planar depth and pose of the camera at world `x = camera_x`.
pub fn render(camera_x: f64) -> (RgbImage, DepthMap, WorldToCamera) {
    let k = intrinsics();
    let on_box = |u: usize, v: usize| {
        let x = (u as f64 - k.cx) / k.fx * BOX_Z + camera_x;
        BOX_ROWS.contains(&v) && (BOX_X.0..=BOX_X.1).contains(&x)
    };
    let image = Image::from_fn(WIDTH, HEIGHT, |u, v| if on_box(u, v) { BOX_COLOUR } else { wall_colour(v) });
    let depth = Image::from_fn(WIDTH, HEIGHT, |u, v| [if on_box(u, v) { BOX_Z } else { WALL_Z } as f32]);
    let pose = WorldToCamera(DMat4::from_translation(DVec3::new(-camera_x, 0.0, 0.0)));
    (image, depth, pose)
}

/// A rendered frame: image, planar depth and pose.
pub type Frame = (RgbImage, DepthMap, WorldToCamera);

/// Frames n-2, n and the target t of the box scene (the camera at x = 0.1, 0.2 and 0.3) and the
/// warp n -> t. The camera moves right, so the wall is uncovered on the right of the box.
pub struct BoxWarp {
    pub k: Intrinsics,
    pub before_last: Frame,
    pub last: Frame,
    pub target: Frame,
    pub warped: Warp,
}

fn view(frame: &Frame) -> FrameView<'_> {
    FrameView { image: &frame.0, depth: &frame.1, pose: &frame.2 }
}

impl BoxWarp {
    pub fn new() -> Self {
        let k = intrinsics();
        let [before_last, last, target] = [0.1, 0.2, 0.3].map(render);
        let warped = warp_forward(&last.0, &last.1, &k, &relative_pose(&last.2, &target.2));
        Self { k, before_last, last, target, warped }
    }

    /// The target's infilling context, with frame n-2 (which the temporal prior needs) and the
    /// ground truth (which the oracle needs) only when asked for.
    pub fn context(&self, with_before_last: bool, with_truth: bool) -> InfillContext<'_> {
        InfillContext {
            intrinsics: &self.k,
            last: view(&self.last),
            before_last: with_before_last.then(|| view(&self.before_last)),
            target_pose: &self.target.2,
            warped: &self.warped,
            ground_truth: with_truth.then_some(&self.target.0),
        }
    }
}

pub const RED: [f32; 3] = [1.0, 0.0, 0.0];
pub const GREEN: [f32; 3] = [0.0, 1.0, 0.0];
pub const BLUE: [f32; 3] = [0.0, 0.0, 1.0];

pub fn classes_from_rows(rows: &[&str]) -> HoleMask {
    // K = known, N = new region, D = disocclusion.
    let classes = rows
        .iter()
        .flat_map(|r| r.chars())
        .map(|c| match c {
            'K' => PixelClass::Known,
            'N' => PixelClass::NewRegion,
            'D' => PixelClass::Disocclusion,
            _ => panic!("bad class {c}"),
        })
        .collect();
    HoleMask::from_classes(rows[0].len(), rows.len(), classes)
}

/// An image whose every pixel has a distinct colour, so a copy says where it came from.
pub fn labelled(w: usize, h: usize) -> RgbImage {
    Image::from_fn(w, h, |u, v| [u as f32 / w as f32, v as f32 / h as f32, 0.5])
}

pub fn assert_all_finite(image: &RgbImage) {
    assert!(image.as_flat().iter().all(|x| x.is_finite()), "non-finite pixel");
}
