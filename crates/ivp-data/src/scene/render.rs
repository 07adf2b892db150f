//! The ray caster: one primary ray through each pixel centre for planar depth, four more on a 2x2
//! grid (offsets +-0.25 px) for antialiased colour, rayon over rows.
//!
//! Speed comes from skipping objects, not from clever intersection code. The rays of one image
//! row (or sub-row, for the colour samples) lie in a plane through the camera centre; that plane
//! cuts an object's bounding box in a convex polygon, and only rays between the polygon's
//! leftmost and rightmost corners can hit the object. So each sub-row keeps an exact column
//! interval per object and each sample tests only the objects whose interval holds it: about as
//! many tests as objects actually overlap there. The room is always hit (every ray from inside
//! leaves it), so its exit is the starting `t_max` and objects only have to beat it.

use glam::{DVec4, Vec3, Vec3A};
use ivp_core::{DepthMap, Intrinsics, RgbImage, WorldToCamera};
use rayon::prelude::*;

use super::description::Scene;
use super::geometry::{Ray, RoomFace, ShapeSeenFrom};
use crate::Frame;

/// Rows of samples within a pixel row, as offsets from the pixel centre: the colour samples'
/// upper row, the centre (depth), the colour samples' lower row.
const SUB_ROWS: [f32; 3] = [-0.25, 0.0, 0.25];
/// Index in [`SUB_ROWS`] of the pixel centre.
const CENTRE_ROW: usize = 1;
/// The colour samples: (column offset, index in [`SUB_ROWS`]).
const COLOR_SAMPLES: [(f32, usize); 4] = [(-0.25, 0), (0.25, 0), (-0.25, 2), (0.25, 2)];
/// Column intervals are widened by this much (pixels) against rounding.
const INTERVAL_PADDING_PX: f32 = 0.1;
/// Cross-section corners closer to the camera plane than this make projection unreliable: the
/// object is then tested along the whole sub-row.
const MIN_PROJECTION_Z: f32 = 1e-3;
/// Corner pairs of a box that share an edge (corners indexed as in [`super::geometry::box_corners`]).
const BOX_EDGES: [(usize, usize); 12] =
    [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)];

/// Generates the camera ray through any image point.
struct PixelRays {
    origin: Vec3A,
    right: Vec3A,
    down: Vec3A,
    forward: Vec3A,
    fx: f32,
    cx: f32,
    cy: f32,
    inv_fx: f32,
    inv_fy: f32,
}

impl PixelRays {
    fn new(pose: &WorldToCamera, k: &Intrinsics) -> Self {
        let camera_to_world = pose.camera_to_world();
        let axis = |c: DVec4| Vec3A::from(c.truncate().as_vec3());
        Self {
            origin: axis(camera_to_world.w_axis),
            right: axis(camera_to_world.x_axis),
            down: axis(camera_to_world.y_axis),
            forward: axis(camera_to_world.z_axis),
            fx: k.fx as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            inv_fx: (1.0 / k.fx) as f32,
            inv_fy: (1.0 / k.fy) as f32,
        }
    }

    /// Camera-space `y / z` of image row `v`.
    #[inline]
    fn slope_of_row(&self, v: f32) -> f32 {
        (v - self.cy) * self.inv_fy
    }

    /// The direction through column 0 of row `v` and the step between columns: the direction
    /// through image point `(u, v)` is `start + u * step`, scaled so that a hit's `t` is its planar
    /// depth (camera-space z).
    #[inline]
    fn row_directions(&self, v: f32) -> (Vec3A, Vec3A) {
        let start = self.forward + self.slope_of_row(v) * self.down - (self.cx * self.inv_fx) * self.right;
        (start, self.inv_fx * self.right)
    }

    /// The image column of camera-space direction `x / z`.
    #[inline]
    fn column(&self, x_over_z: f32) -> f32 {
        self.fx * x_over_z + self.cx
    }
}

/// Closed column interval `[lo, hi]`; empty when `lo > hi`.
#[derive(Clone, Copy, Debug)]
struct Columns {
    lo: f32,
    hi: f32,
}

impl Columns {
    const NONE: Self = Self { lo: f32::INFINITY, hi: f32::NEG_INFINITY };
    const ALL: Self = Self { lo: f32::NEG_INFINITY, hi: f32::INFINITY };

    #[inline]
    fn contains(&self, u: f32) -> bool {
        self.lo <= u && u <= self.hi
    }

    fn is_empty(&self) -> bool {
        self.lo > self.hi
    }
}

/// The columns of image row `v` (fractional) whose rays may hit a box with camera-space `corners`.
fn columns_of_box(corners: &[Vec3; 8], v: f32, rays: &PixelRays) -> Columns {
    // The row's rays span the plane y = slope * z; side[i] says on which side of it corner i lies.
    let slope = rays.slope_of_row(v);
    let side: [f32; 8] = std::array::from_fn(|i| corners[i].y - slope * corners[i].z);
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut behind = 0;
    let mut crossings = 0;
    for (a, b) in BOX_EDGES {
        if (side[a] <= 0.0) == (side[b] <= 0.0) {
            continue;
        }
        // A corner of the cross-section polygon.
        let p = corners[a].lerp(corners[b], side[a] / (side[a] - side[b]));
        crossings += 1;
        if p.z < MIN_PROJECTION_Z {
            behind += 1;
            continue;
        }
        lo = lo.min(p.x / p.z);
        hi = hi.max(p.x / p.z);
    }
    match (crossings, behind) {
        (0, _) => Columns::NONE,
        (c, b) if b == c => Columns::NONE,
        (_, 0) => Columns { lo: rays.column(lo) - INTERVAL_PADDING_PX, hi: rays.column(hi) + INTERVAL_PADDING_PX },
        _ => Columns::ALL,
    }
}

/// An object worth testing within one pixel row: its index, its shape as seen from the camera
/// and its columns per sub-row.
#[derive(Clone, Copy, Debug)]
struct RowCandidate {
    object: usize,
    shape: ShapeSeenFrom,
    columns: [Columns; 3],
}

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Surface {
    Room(RoomFace),
    Object(usize),
}

impl Scene {
    /// Renders the view of camera `pose`: colours (2x2 supersampled) and planar depth (through the
    /// pixel centres). Every pixel sees the room or an object, so every depth is finite and > 0
    /// as long as the camera is inside the room.
    pub fn render(&self, pose: &WorldToCamera, k: &Intrinsics, width: usize, height: usize) -> Frame {
        let rays = PixelRays::new(pose, k);
        let world_to_camera = pose.0.as_mat4();
        let objects: Vec<(ShapeSeenFrom, [Vec3; 8])> = self
            .objects
            .iter()
            .map(|o| {
                let corners = o.shape.bounding_corners().map(|c| world_to_camera.transform_point3(c));
                (o.shape.seen_from(rays.origin), corners)
            })
            .collect();
        let mut image = RgbImage::zeros(width, height);
        let mut depth = DepthMap::zeros(width, height);
        image
            .pixels_mut()
            .par_chunks_mut(width)
            .zip(depth.pixels_mut().par_chunks_mut(width))
            .enumerate()
            .for_each(|(v, (colors, depths))| self.render_row(&rays, &objects, v as f32, colors, depths));
        Frame { image, depth }
    }

    fn render_row(
        &self,
        rays: &PixelRays,
        objects: &[(ShapeSeenFrom, [Vec3; 8])],
        v: f32,
        colors: &mut [[f32; 3]],
        depths: &mut [[f32; 1]],
    ) {
        let candidates: Vec<RowCandidate> = objects
            .iter()
            .enumerate()
            .map(|(object, (shape, corners))| RowCandidate {
                object,
                shape: *shape,
                columns: SUB_ROWS.map(|dv| columns_of_box(corners, v + dv, rays)),
            })
            .filter(|c| c.columns.iter().any(|cols| !cols.is_empty()))
            .collect();
        let directions = SUB_ROWS.map(|dv| rays.row_directions(v + dv));
        let ray = |u: f32, sub_row: usize| {
            let (start, step) = directions[sub_row];
            Ray { origin: rays.origin, dir: start + u * step }
        };
        for (u, (color, depth)) in colors.iter_mut().zip(depths.iter_mut()).enumerate() {
            let u = u as f32;
            *depth = [self.trace(&ray(u, CENTRE_ROW), u, CENTRE_ROW, &candidates).0];
            let samples = COLOR_SAMPLES.map(|(du, sub_row)| {
                let ray = ray(u + du, sub_row);
                let (t, surface) = self.trace(&ray, u + du, sub_row, &candidates);
                (ray.at(t), surface)
            });
            *color = (0.25 * self.shade_pixel(&samples)).clamp(Vec3::ZERO, Vec3::ONE).to_array();
        }
    }

    /// The nearest hit of a ray through column `u` of sub-row `sub_row`: its `t` and surface.
    #[inline]
    fn trace(&self, ray: &Ray, u: f32, sub_row: usize, candidates: &[RowCandidate]) -> (f32, Surface) {
        let (mut t, face) = self.room.exit(ray);
        let mut surface = Surface::Room(face);
        for c in candidates {
            if c.columns[sub_row].contains(u) {
                if let Some(hit) = c.shape.intersect(ray.dir, t) {
                    t = hit;
                    surface = Surface::Object(c.object);
                }
            }
        }
        (t, surface)
    }

    /// The sum of the shaded colours of a pixel's colour samples, given as hit points and
    /// surfaces. Most pixels lie within one surface, whose texture then shades all four samples at
    /// once (see [`super::Texture::pixel_colors`]).
    fn shade_pixel(&self, samples: &[(Vec3A, Surface); 4]) -> Vec3 {
        let surface_point = |(p, surface): (Vec3A, Surface)| match surface {
            Surface::Room(face) => self.room.surface_at(face, p),
            Surface::Object(i) => self.objects[i].shape.surface_at(p),
        };
        let texture = |surface: Surface| match surface {
            Surface::Room(face) => &self.room_textures[face as usize],
            Surface::Object(i) => &self.objects[i].texture,
        };
        let points = samples.map(surface_point);
        let colors = if samples.iter().all(|s| s.1 == samples[0].1) {
            texture(samples[0].1).pixel_colors(&points.map(|p| p.uv))
        } else {
            std::array::from_fn(|i| texture(samples[i].1).color_at(points[i].uv))
        };
        colors.iter().zip(&points).map(|(&color, point)| color * self.lambert(point.normal)).sum()
    }

    /// Lambert shading factor of a surface with unit `normal`: ambient plus directional light.
    #[inline]
    fn lambert(&self, normal: Vec3A) -> f32 {
        let light = &self.light;
        light.ambient + light.intensity * normal.dot(Vec3A::from(light.direction)).max(0.0)
    }
}
