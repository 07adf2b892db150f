//! Rays and the few primitives a scene is made of, in world space (metres, z up).
//!
//! Every primitive answers two questions: where a ray first meets it ([`Shape::intersect`], the hot
//! path, f32 and branch-light) and what the surface is like at a point found that way
//! ([`Shape::surface_at`]: normal and texture coordinates, asked once per shaded sample).
//! Texture coordinates are metres along the surface, so a texture keeps its scale on every object
//! and stays attached to the surface when the camera moves.

use glam::{Vec2, Vec3, Vec3A};

/// Hits closer than this to the ray origin are ignored, so a ray never re-hits its own surface.
pub const T_MIN: f32 = 1e-4;

/// A ray `origin + t * dir`. Camera rays keep `dir` unnormalised with a camera-space z component of
/// 1, so that `t` of a hit *is* the planar depth of that hit.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub origin: Vec3A,
    pub dir: Vec3A,
}

impl Ray {
    #[inline]
    pub fn at(&self, t: f32) -> Vec3A {
        self.origin + t * self.dir
    }
}

/// What shading needs to know about a surface point.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// Unit normal, pointing out of the solid (into the room for the room's faces).
    pub normal: Vec3A,
    /// Texture coordinates in metres along the surface.
    pub uv: Vec2,
}

/// A sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub centre: Vec3,
    pub radius: f32,
}

impl Sphere {
    fn surface_at(&self, p: Vec3A) -> SurfacePoint {
        // A hit point lies on the surface up to rounding: dividing by the radius normalises.
        let normal = (p - Vec3A::from(self.centre)) * (1.0 / self.radius);
        // Longitude and colatitude as arc lengths: metres on the sphere's surface.
        let colatitude = fast_atan2(Vec2::new(normal.x, normal.y).length(), normal.z);
        let uv = Vec2::new(fast_atan2(normal.y, normal.x), colatitude) * self.radius;
        SurfacePoint { normal, uv }
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        (self.centre - Vec3::splat(self.radius), self.centre + Vec3::splat(self.radius))
    }
}

/// A vertical cylinder with both caps, standing on `base` (the centre of its bottom disc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    pub base: Vec3,
    pub radius: f32,
    pub height: f32,
}

impl Cylinder {
    fn surface_at(&self, p: Vec3A) -> SurfacePoint {
        let local = p - Vec3A::from(self.base);
        // A cap hit lies on the cap's plane up to rounding; a side hit that close to a cap is on the
        // rim, where either normal shades the same sub-pixel sliver.
        let cap_tolerance = 1e-4 * (1.0 + self.height);
        if local.z.abs() < cap_tolerance || (local.z - self.height).abs() < cap_tolerance {
            let up = if local.z > 0.5 * self.height { 1.0 } else { -1.0 };
            return SurfacePoint { normal: Vec3A::new(0.0, 0.0, up), uv: Vec2::new(local.x, local.y) };
        }
        let normal = Vec3A::new(local.x, local.y, 0.0) * (1.0 / self.radius);
        SurfacePoint { normal, uv: Vec2::new(fast_atan2(normal.y, normal.x) * self.radius, local.z) }
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        let r = Vec3::new(self.radius, self.radius, 0.0);
        (self.base - r, self.base + r + Vec3::new(0.0, 0.0, self.height))
    }
}

/// A box turned by `yaw` radians about the vertical axis through its centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct YawedBox {
    centre: Vec3,
    half_size: Vec3,
    yaw: f32,
    // Cached for the hot path.
    cos_yaw: f32,
    sin_yaw: f32,
}

impl YawedBox {
    pub fn new(centre: Vec3, half_size: Vec3, yaw: f32) -> Self {
        Self { centre, half_size, yaw, cos_yaw: yaw.cos(), sin_yaw: yaw.sin() }
    }

    pub fn centre(&self) -> Vec3 {
        self.centre
    }

    pub fn half_size(&self) -> Vec3 {
        self.half_size
    }

    pub fn yaw(&self) -> f32 {
        self.yaw
    }

    /// A world vector in the box's own axes (rotation by `-yaw`).
    #[inline]
    fn world_to_local(&self, v: Vec3A) -> Vec3A {
        Vec3A::new(self.cos_yaw * v.x + self.sin_yaw * v.y, -self.sin_yaw * v.x + self.cos_yaw * v.y, v.z)
    }

    #[inline]
    fn local_to_world(&self, v: Vec3A) -> Vec3A {
        Vec3A::new(self.cos_yaw * v.x - self.sin_yaw * v.y, self.sin_yaw * v.x + self.cos_yaw * v.y, v.z)
    }

    fn surface_at(&self, p: Vec3A) -> SurfacePoint {
        let local = self.world_to_local(p - Vec3A::from(self.centre));
        let scaled = (local / Vec3A::from(self.half_size)).abs();
        // The face hit is the one the point is (relatively) farthest out on.
        let (normal, uv) = if scaled.x >= scaled.y && scaled.x >= scaled.z {
            (Vec3A::new(local.x.signum(), 0.0, 0.0), Vec2::new(local.y, local.z))
        } else if scaled.y >= scaled.z {
            (Vec3A::new(0.0, local.y.signum(), 0.0), Vec2::new(local.x, local.z))
        } else {
            (Vec3A::new(0.0, 0.0, local.z.signum()), Vec2::new(local.x, local.y))
        };
        SurfacePoint { normal: self.local_to_world(normal), uv }
    }

    /// The 8 corners, indexed by bits (bit 0: +x side, bit 1: +y side, bit 2: top) in its own axes.
    fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            let sign = |bit: usize| if i & bit == 0 { -1.0 } else { 1.0 };
            let local = Vec3A::new(sign(1), sign(2), sign(4)) * Vec3A::from(self.half_size);
            Vec3::from(self.local_to_world(local)) + self.centre
        })
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        let (c, s) = (self.cos_yaw.abs(), self.sin_yaw.abs());
        let h = self.half_size;
        let extent = Vec3::new(c * h.x + s * h.y, s * h.x + c * h.y, h.z);
        (self.centre - extent, self.centre + extent)
    }
}

/// The nearest of two ordered roots `t0 <= t1` in `(T_MIN, t_max)`.
#[inline]
fn first_root_in_range(t0: f32, t1: f32, t_max: f32) -> Option<f32> {
    let t = if t0 > T_MIN { t0 } else { t1 };
    (t > T_MIN && t < t_max).then_some(t)
}

/// `y.atan2(x)` to within 2e-5 rad, several times faster than libm's (it runs for every shaded
/// sample on a sphere or cylinder; texture coordinates need no more precision).
#[inline]
pub fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    if ax == 0.0 && ay == 0.0 {
        return 0.0;
    }
    // atan on [0, 1] by a minimax polynomial in the ratio of the smaller to the larger magnitude.
    let ratio = ax.min(ay) / ax.max(ay);
    let r2 = ratio * ratio;
    let mut angle = ratio * (0.999_866 + r2 * (-0.330_299_5 + r2 * (0.180_141 + r2 * (-0.085_133 + r2 * 0.020_835_1))));
    if ay > ax {
        angle = FRAC_PI_2 - angle;
    }
    if x < 0.0 {
        angle = PI - angle;
    }
    if y < 0.0 {
        -angle
    } else {
        angle
    }
}

/// A solid object's shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    Sphere(Sphere),
    Cylinder(Cylinder),
    Box(YawedBox),
}

impl Shape {
    /// The nearest hit in `(T_MIN, t_max)`, if any.
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<f32> {
        self.seen_from(ray.origin).intersect(ray.dir, t_max)
    }

    /// The shape prepared for rays from `origin`.
    pub fn seen_from(&self, origin: Vec3A) -> ShapeSeenFrom {
        match self {
            Shape::Sphere(s) => {
                ShapeSeenFrom::Sphere { to_origin: origin - Vec3A::from(s.centre), radius_squared: s.radius * s.radius }
            }
            Shape::Cylinder(c) => ShapeSeenFrom::Cylinder {
                to_origin: origin - Vec3A::from(c.base),
                radius_squared: c.radius * c.radius,
                height: c.height,
            },
            Shape::Box(b) => ShapeSeenFrom::Box {
                local_origin: b.world_to_local(origin - Vec3A::from(b.centre)),
                half_size: Vec3A::from(b.half_size),
                cos_yaw: b.cos_yaw,
                sin_yaw: b.sin_yaw,
            },
        }
    }

    /// Normal and texture coordinates at a point on the surface.
    pub fn surface_at(&self, p: Vec3A) -> SurfacePoint {
        match self {
            Shape::Sphere(s) => s.surface_at(p),
            Shape::Cylinder(c) => c.surface_at(p),
            Shape::Box(b) => b.surface_at(p),
        }
    }

    /// The corners of a box around the shape, indexed by bits as [`box_corners`]: the box itself
    /// for a box, the world-axis-aligned bounds for the others.
    pub fn bounding_corners(&self) -> [Vec3; 8] {
        match self {
            Shape::Box(b) => b.corners(),
            _ => box_corners(self.bounds()),
        }
    }

    /// World-axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        match self {
            Shape::Sphere(s) => s.bounds(),
            Shape::Cylinder(c) => c.bounds(),
            Shape::Box(b) => b.bounds(),
        }
    }
}

/// The corners of axis-aligned bounds `(lo, hi)`; bit 0 of the index picks `hi.x`, bit 1 `hi.y`,
/// bit 2 `hi.z`, so corners `i` and `i | bit` share an edge.
pub fn box_corners((lo, hi): (Vec3, Vec3)) -> [Vec3; 8] {
    std::array::from_fn(|i| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

/// A shape prepared for many rays from one origin (a camera centre): what depends only on the
/// origin is computed once per frame instead of once per ray.
#[derive(Clone, Copy, Debug)]
pub enum ShapeSeenFrom {
    Sphere {
        to_origin: Vec3A,
        radius_squared: f32,
    },
    /// `to_origin` is relative to the centre of the bottom disc.
    Cylinder {
        to_origin: Vec3A,
        radius_squared: f32,
        height: f32,
    },
    /// `local_origin` is in the box's own axes, relative to its centre.
    Box {
        local_origin: Vec3A,
        half_size: Vec3A,
        cos_yaw: f32,
        sin_yaw: f32,
    },
}

impl ShapeSeenFrom {
    /// The nearest hit of the ray `origin + t * dir` in `(T_MIN, t_max)`, if any.
    #[inline]
    pub fn intersect(&self, dir: Vec3A, t_max: f32) -> Option<f32> {
        match *self {
            Self::Sphere { to_origin, radius_squared } => {
                let a = dir.length_squared();
                let half_b = to_origin.dot(dir);
                // Squared distance from the centre to the ray's line computed directly: `b^2 - a c`
                // would cancel catastrophically in f32 for thin objects seen from metres away.
                let closest = to_origin - (half_b / a) * dir;
                let discriminant = radius_squared - closest.length_squared();
                if discriminant < 0.0 {
                    return None;
                }
                let root = (a * discriminant).sqrt();
                first_root_in_range((-half_b - root) / a, (-half_b + root) / a, t_max)
            }
            Self::Cylinder { to_origin, radius_squared, height } => {
                intersect_cylinder(to_origin, radius_squared, height, dir, t_max)
            }
            Self::Box { local_origin, half_size, cos_yaw, sin_yaw } => {
                let local_dir =
                    Vec3A::new(cos_yaw * dir.x + sin_yaw * dir.y, -sin_yaw * dir.x + cos_yaw * dir.y, dir.z);
                let inv_dir = local_dir.recip();
                // Slab test; an axis-parallel ray gives +-inf here, which min/max handle.
                let t0 = (-half_size - local_origin) * inv_dir;
                let t1 = (half_size - local_origin) * inv_dir;
                let t_enter = t0.min(t1).max_element();
                let t_exit = t0.max(t1).min_element();
                if t_enter > t_exit {
                    return None;
                }
                first_root_in_range(t_enter, t_exit, t_max)
            }
        }
    }
}

/// A vertical cylinder with caps, for a ray from `o` (relative to the bottom disc's centre).
#[inline]
fn intersect_cylinder(o: Vec3A, radius_squared: f32, height: f32, dir: Vec3A, t_max: f32) -> Option<f32> {
    let mut best = t_max;
    let a = dir.x * dir.x + dir.y * dir.y;
    if a > 0.0 {
        // Same cancellation-free form as the sphere, in the horizontal plane.
        let half_b = o.x * dir.x + o.y * dir.y;
        let (cx, cy) = (o.x - half_b / a * dir.x, o.y - half_b / a * dir.y);
        let discriminant = radius_squared - (cx * cx + cy * cy);
        if discriminant >= 0.0 {
            let root = (a * discriminant).sqrt();
            for t in [(-half_b - root) / a, (-half_b + root) / a] {
                let z = o.z + t * dir.z;
                if t > T_MIN && t < best && (0.0..=height).contains(&z) {
                    best = t;
                    break;
                }
            }
        }
    }
    if dir.z != 0.0 {
        for z_cap in [0.0, height] {
            let t = (z_cap - o.z) / dir.z;
            if t > T_MIN && t < best {
                let (x, y) = (o.x + t * dir.x, o.y + t * dir.y);
                if x * x + y * y <= radius_squared {
                    best = t;
                }
            }
        }
    }
    (best < t_max).then_some(best)
}

/// One of the six faces of a [`Room`], in the order of [`Room::FACES`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RoomFace {
    /// The wall at `min.x`.
    WallMinX = 0,
    WallMaxX = 1,
    WallMinY = 2,
    WallMaxY = 3,
    Floor = 4,
    Ceiling = 5,
}

/// Inward normal and the two world axes of the texture coordinates of each [`RoomFace`].
const ROOM_FACE_FRAMES: [(Vec3A, Vec3A, Vec3A); 6] = [
    (Vec3A::X, Vec3A::Y, Vec3A::Z),
    (Vec3A::NEG_X, Vec3A::Y, Vec3A::Z),
    (Vec3A::Y, Vec3A::X, Vec3A::Z),
    (Vec3A::NEG_Y, Vec3A::X, Vec3A::Z),
    (Vec3A::Z, Vec3A::X, Vec3A::Y),
    (Vec3A::NEG_Z, Vec3A::X, Vec3A::Y),
];

/// The inside of an axis-aligned box: floor at `min.z`, ceiling at `max.z`. Every ray from inside
/// leaves it through some face, so every pixel sees something at a finite depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Room {
    pub min: Vec3,
    pub max: Vec3,
}

impl Room {
    pub const FACES: [RoomFace; 6] = [
        RoomFace::WallMinX,
        RoomFace::WallMaxX,
        RoomFace::WallMinY,
        RoomFace::WallMaxY,
        RoomFace::Floor,
        RoomFace::Ceiling,
    ];

    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpgt(self.min).all() && p.cmplt(self.max).all()
    }

    /// Where a ray from inside the room leaves it: `t` and the face.
    #[inline]
    pub fn exit(&self, ray: &Ray) -> (f32, RoomFace) {
        let inv_dir = ray.dir.recip();
        let t_min_side = (Vec3A::from(self.min) - ray.origin) * inv_dir;
        let t_max_side = (Vec3A::from(self.max) - ray.origin) * inv_dir;
        // Moving towards +axis the ray leaves through the max face, else through the min face.
        let t_exit = t_min_side.max(t_max_side);
        let candidates = [
            (t_exit.x, ray.dir.x > 0.0, RoomFace::WallMinX, RoomFace::WallMaxX),
            (t_exit.y, ray.dir.y > 0.0, RoomFace::WallMinY, RoomFace::WallMaxY),
            (t_exit.z, ray.dir.z > 0.0, RoomFace::Floor, RoomFace::Ceiling),
        ];
        let mut best = (f32::INFINITY, RoomFace::Floor);
        for (t, positive, min_face, max_face) in candidates {
            if t < best.0 {
                best = (t, if positive { max_face } else { min_face });
            }
        }
        best
    }

    /// Inward normal and texture coordinates of a face at point `p`.
    #[inline]
    pub fn surface_at(&self, face: RoomFace, p: Vec3A) -> SurfacePoint {
        // A table rather than a match: faces change often along a row, and a mispredicted jump
        // costs more than the rest of this function.
        let (normal, u_axis, v_axis) = ROOM_FACE_FRAMES[face as usize];
        let uv = Vec2::new(p.dot(u_axis), p.dot(v_axis));
        SurfacePoint { normal, uv }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(origin: [f32; 3], dir: [f32; 3]) -> Ray {
        Ray { origin: Vec3A::from(origin), dir: Vec3A::from(dir) }
    }

    #[test]
    fn sphere_hit_is_at_the_near_surface() {
        let s = Shape::Sphere(Sphere { centre: Vec3::new(0.0, 5.0, 0.0), radius: 1.0 });
        let t = s.intersect(&ray([0.0, 0.0, 0.0], [0.0, 2.0, 0.0]), f32::INFINITY).unwrap();
        assert!((t - 2.0).abs() < 1e-6, "{t}");
        let n = s.surface_at(Vec3A::new(0.0, 4.0, 0.0)).normal;
        assert!((n - Vec3A::NEG_Y).length() < 1e-6);
        assert!(s.intersect(&ray([0.0, 0.0, 0.0], [0.0, 2.0, 0.0]), 1.5).is_none(), "t_max is respected");
        assert!(s.intersect(&ray([0.0, 0.0, 1.01], [0.0, 1.0, 0.0]), f32::INFINITY).is_none());
    }

    #[test]
    fn thin_cylinder_far_away_is_hit_exactly() {
        let c = Shape::Cylinder(Cylinder { base: Vec3::new(0.0, 10.0, 0.0), radius: 0.02, height: 3.0 });
        let t = c.intersect(&ray([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]), f32::INFINITY).unwrap();
        assert!((t - 9.98).abs() < 1e-5, "{t}");
        assert!(c.intersect(&ray([0.021, 0.0, 1.0], [0.0, 1.0, 0.0]), f32::INFINITY).is_none());
        // From above, the top cap.
        let t = c.intersect(&ray([0.0, 10.0, 5.0], [0.0, 0.0, -1.0]), f32::INFINITY).unwrap();
        assert!((t - 2.0).abs() < 1e-6);
        let n = c.surface_at(Vec3A::new(0.0, 10.0, 3.0)).normal;
        assert_eq!(n, Vec3A::Z);
    }

    #[test]
    fn yawed_box_face_and_bounds() {
        let b = YawedBox::new(Vec3::new(0.0, 5.0, 0.0), Vec3::new(1.0, 0.5, 0.5), std::f32::consts::FRAC_PI_2);
        // Turned by 90 degrees: the long side now lies along y.
        let t = Shape::Box(b).intersect(&ray([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]), f32::INFINITY).unwrap();
        assert!((t - 4.0).abs() < 1e-5, "{t}");
        let n = Shape::Box(b).surface_at(Vec3A::new(0.0, 4.0, 0.0)).normal;
        assert!((n - Vec3A::NEG_Y).length() < 1e-5, "{n}");
        let (lo, hi) = Shape::Box(b).bounds();
        assert!((lo - Vec3::new(-0.5, 4.0, -0.5)).length() < 1e-5 && (hi - Vec3::new(0.5, 6.0, 0.5)).length() < 1e-5);
    }

    #[test]
    fn fast_atan2_is_close_to_libm() {
        let mut worst = 0.0f32;
        for i in 0..2000 {
            // Every direction, just short of -pi and pi (where atan2 jumps).
            let angle = (i as f32 / 1000.0 - 1.0) * 0.9999 * std::f32::consts::PI;
            for r in [0.01f32, 1.0, 7.5] {
                let (y, x) = (r * angle.sin(), r * angle.cos());
                worst = worst.max((fast_atan2(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 2e-5, "{worst}");
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
        assert_eq!(fast_atan2(0.0, -1.0), std::f32::consts::PI);
    }

    #[test]
    fn every_ray_leaves_the_room() {
        let room = Room { min: Vec3::new(-2.0, -1.0, 0.0), max: Vec3::new(3.0, 8.0, 3.0) };
        let (t, face) = room.exit(&ray([0.0, 0.0, 1.5], [0.0, 1.0, 0.0]));
        assert_eq!((t, face), (8.0, RoomFace::WallMaxY));
        let (t, face) = room.exit(&ray([0.0, 0.0, 1.5], [0.1, 0.2, -1.0]));
        assert_eq!(face, RoomFace::Floor);
        assert!((t - 1.5).abs() < 1e-6);
    }
}
