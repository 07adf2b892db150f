//! Procedural textures: functions of surface coordinates in metres, so that a pattern stays
//! attached to its surface and has the same scale in every frame.
//!
//! Infilling should not be trivial: patterns have hard edges (checker, stripes, bricks, tiles) or
//! smooth irregular variation (value noise, gradients), and every texture is modulated by a
//! low-frequency "grain" so that no two patches of a surface are exactly alike.

use std::f32::consts::TAU;

use glam::{Affine2, Vec2, Vec3};
use rand::Rng;

/// The pattern of a texture; sizes in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pattern {
    /// Squares of side `cell`, alternating palette colours 0 and 1.
    Checker { cell: f32 },
    /// Parallel stripes of colours 0 and 1; colour 0 takes the fraction `duty` of each period.
    Stripes { period: f32, duty: f32 },
    /// Running bond bricks of size `brick` separated by mortar joints (colour 3) of width `mortar`;
    /// each brick's colour lies between colours 0 and 1, with an occasional colour 2 brick.
    Bricks { brick: Vec2, mortar: f32 },
    /// Fractal value noise with features of about `scale`, blending colours 0, 1 and 2.
    Noise { scale: f32 },
    /// A ramp between colours 0 and 1 and back over each `period` (a triangle wave).
    Gradient { period: f32 },
    /// Rectangular tiles of size `cell`, each in one colour of the palette drawn at random.
    Tiles { cell: Vec2 },
}

/// A pattern with its colours, placement and grain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Texture {
    pub pattern: Pattern,
    /// Display (sRGB) colours in `[0, 1]`; shading multiplies them directly.
    pub palette: [Vec3; 4],
    /// Maps surface coordinates to pattern coordinates (rotation and offset).
    pub placement: Affine2,
    /// Strength of the multiplicative low-frequency brightness variation, in `[0, 1)`.
    pub grain: f32,
    /// Feature size of the grain, metres.
    pub grain_scale: f32,
    /// Decorrelates the noise of different textures.
    pub seed: u32,
}

impl Texture {
    /// A uniform colour (for tests and plain surfaces).
    pub fn plain(color: Vec3) -> Self {
        Self {
            pattern: Pattern::Checker { cell: 1.0 },
            palette: [color; 4],
            placement: Affine2::IDENTITY,
            grain: 0.0,
            grain_scale: 1.0,
            seed: 0,
        }
    }

    /// The colour at surface coordinates `uv` (metres).
    pub fn color_at(&self, uv: Vec2) -> Vec3 {
        let p = self.placement.transform_point2(uv);
        let base = if self.is_smooth() { self.smooth_pattern_at(p) } else { self.hard_pattern_at(p) };
        base * self.grain_at(uv)
    }

    /// The colours of the four colour samples of one pixel, all on this texture. The smooth parts
    /// (grain, and the noise and gradient patterns, whose features span several pixels) are
    /// evaluated once at the samples' centroid: sampling them four times would change the result
    /// by a fraction of a grey level at four times the cost, and texturing is most of the cost of
    /// a frame. Hard-edged patterns are evaluated at every sample, so their edges stay antialiased.
    pub fn pixel_colors(&self, uvs: &[Vec2; 4]) -> [Vec3; 4] {
        let centroid = 0.25 * (uvs[0] + uvs[1] + uvs[2] + uvs[3]);
        let grain = self.grain_at(centroid);
        if self.is_smooth() {
            let c = self.smooth_pattern_at(self.placement.transform_point2(centroid)) * grain;
            return [c; 4];
        }
        uvs.map(|uv| self.hard_pattern_at(self.placement.transform_point2(uv)) * grain)
    }

    fn is_smooth(&self) -> bool {
        matches!(self.pattern, Pattern::Noise { .. } | Pattern::Gradient { .. })
    }

    /// The brightness factor of the grain at `uv`.
    fn grain_at(&self, uv: Vec2) -> f32 {
        if self.grain == 0.0 {
            return 1.0;
        }
        let g = fractal_noise(uv / self.grain_scale, self.seed.wrapping_add(0x9e37_79b9), 2);
        1.0 + self.grain * (2.0 * g - 1.0)
    }

    /// A smooth pattern at pattern coordinates `p`.
    fn smooth_pattern_at(&self, p: Vec2) -> Vec3 {
        let [c0, c1, c2, _] = self.palette;
        match self.pattern {
            Pattern::Noise { scale } => {
                let n = fractal_noise(p / scale, self.seed, 3);
                // Two blends with a soft threshold give patches rather than a uniform haze.
                let mix = c0.lerp(c1, smoothstep(0.3, 0.7, n));
                mix.lerp(c2, smoothstep(0.55, 0.8, fractal_noise(p / (2.0 * scale), self.seed ^ 0x5bd1_e995, 2)))
            }
            Pattern::Gradient { period } => {
                let phase = fract(p.x / period);
                c0.lerp(c1, 1.0 - (2.0 * phase - 1.0).abs())
            }
            _ => self.hard_pattern_at(p),
        }
    }

    /// A hard-edged pattern at pattern coordinates `p`.
    fn hard_pattern_at(&self, p: Vec2) -> Vec3 {
        let [c0, c1, _, _] = self.palette;
        match self.pattern {
            Pattern::Checker { cell } => {
                let cell = (p / cell).floor();
                if (cell.x as i64 + cell.y as i64) & 1 == 0 {
                    c0
                } else {
                    c1
                }
            }
            Pattern::Stripes { period, duty } => {
                if fract(p.x / period) < duty {
                    c0
                } else {
                    c1
                }
            }
            Pattern::Bricks { brick, mortar } => self.brick_color(p, brick, mortar),
            Pattern::Tiles { cell } => {
                let cell = (p / cell).floor();
                self.palette[(lattice_hash(cell.x as i32, cell.y as i32, self.seed) >> 30) as usize]
            }
            Pattern::Noise { .. } | Pattern::Gradient { .. } => self.smooth_pattern_at(p),
        }
    }

    fn brick_color(&self, p: Vec2, brick: Vec2, mortar: f32) -> Vec3 {
        let row = (p.y / brick.y).floor();
        // Every other row is shifted by half a brick (running bond).
        let x = p.x / brick.x + if (row as i64) & 1 == 1 { 0.5 } else { 0.0 };
        let column = x.floor();
        let (in_x, in_y) = ((x - column) * brick.x, p.y - row * brick.y);
        if in_x < mortar || in_y < mortar {
            return self.palette[3];
        }
        let h = lattice_hash(column as i32, row as i32, self.seed);
        if h >> 29 == 0 {
            return self.palette[2];
        }
        self.palette[0].lerp(self.palette[1], unit_float(h))
    }

    /// A random texture: pattern, palette, placement and grain.
    pub fn random(rng: &mut impl Rng) -> Self {
        let pattern = match rng.random_range(0..6) {
            0 => Pattern::Checker { cell: rng.random_range(0.15..0.6) },
            1 => Pattern::Stripes { period: rng.random_range(0.15..0.8), duty: rng.random_range(0.3..0.7) },
            2 => {
                let height = rng.random_range(0.1..0.25);
                let brick = Vec2::new(height * rng.random_range(1.8..3.5), height);
                Pattern::Bricks { brick, mortar: rng.random_range(0.012..0.03) }
            }
            3 => Pattern::Noise { scale: rng.random_range(0.25..1.0) },
            4 => Pattern::Gradient { period: rng.random_range(0.3..2.0) },
            _ => Pattern::Tiles { cell: Vec2::new(rng.random_range(0.15..0.6), rng.random_range(0.15..0.6)) },
        };
        let palette = random_palette(rng);
        // Bricks and tiles look like building materials only when level; other patterns may turn.
        let angle = match pattern {
            Pattern::Bricks { .. } | Pattern::Tiles { .. } => 0.0,
            _ if rng.random_bool(0.5) => rng.random_range(0.0..TAU),
            _ => 0.0,
        };
        let offset = Vec2::new(rng.random_range(0.0..10.0), rng.random_range(0.0..10.0));
        Self {
            pattern,
            palette,
            placement: Affine2::from_angle_translation(angle, offset),
            grain: if rng.random_bool(0.5) { rng.random_range(0.05..0.3) } else { 0.0 },
            grain_scale: rng.random_range(0.3..1.5),
            seed: rng.random(),
        }
    }
}

/// Four colours: two that contrast clearly (the pattern's main pair) and two more.
fn random_palette(rng: &mut impl Rng) -> [Vec3; 4] {
    let first = random_color(rng);
    let second = loop {
        let c = random_color(rng);
        if (luma(c) - luma(first)).abs() > 0.12 || (c - first).length() > 0.35 {
            break c;
        }
    };
    [first, second, random_color(rng), random_color(rng)]
}

fn random_color(rng: &mut impl Rng) -> Vec3 {
    hsv_to_rgb(rng.random_range(0.0..1.0), rng.random_range(0.15..0.9), rng.random_range(0.25..0.95))
}

fn luma(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// HSV (all in `[0, 1]`) to RGB.
pub fn hsv_to_rgb(hue: f32, saturation: f32, value: f32) -> Vec3 {
    let h = hue.rem_euclid(1.0) * 6.0;
    let f = |n: f32| {
        let k = (n + h) % 6.0;
        value - value * saturation * (k.min(4.0 - k).clamp(0.0, 1.0))
    };
    Vec3::new(f(5.0), f(3.0), f(1.0))
}

fn smoothstep(edge0: f32, edge1: f32, x: f32) -> f32 {
    let t = ((x - edge0) / (edge1 - edge0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A 32-bit hash of a lattice point, mixed just enough for textures (three multiplications: it
/// runs for every corner of every noise cell of every sample).
#[inline]
fn lattice_hash(x: i32, y: i32, seed: u32) -> u32 {
    let mut h = seed ^ (x as u32).wrapping_mul(0x8da6_b343) ^ (y as u32).wrapping_mul(0xd816_3841);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^ (h >> 12)
}

/// The top 24 bits of a hash as a float in `[0, 1)`.
#[inline]
fn unit_float(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Lattice cells per period of [`value_noise`].
const NOISE_PERIOD: usize = 256;

/// A fixed random permutation of `0..256` (Perlin's hashing of lattice points by table look-ups:
/// much cheaper than an arithmetic hash, which matters at 4 corners x several octaves per sample).
static PERMUTATION: [u8; NOISE_PERIOD] = shuffled_bytes(0x1d8e_4e27_c47d_124f);

const fn shuffled_bytes(seed: u64) -> [u8; NOISE_PERIOD] {
    let mut table = [0u8; NOISE_PERIOD];
    let mut i = 0;
    while i < NOISE_PERIOD {
        table[i] = i as u8;
        i += 1;
    }
    // Fisher-Yates with a xorshift64 generator.
    let mut state = seed;
    let mut i = NOISE_PERIOD - 1;
    while i > 0 {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let j = (state % (i as u64 + 1)) as usize;
        let t = table[i];
        table[i] = table[j];
        table[j] = t;
        i -= 1;
    }
    table
}

/// Value noise in `[0, 1]` with features of size 1: random values on the integer lattice
/// (periodic every 256 cells), smoothly interpolated. `seed` shifts the lattice, so different
/// seeds give unrelated patterns.
#[inline]
fn value_noise(p: Vec2, seed: u32) -> f32 {
    let cell = p.floor();
    let f = p - cell;
    let x = (cell.x as i32 as u32).wrapping_add(seed) as usize;
    let y = (cell.y as i32 as u32).wrapping_add(seed >> 8) as usize;
    let column = |x: usize| PERMUTATION[x % NOISE_PERIOD] as usize;
    let value = |col: usize, y: usize| PERMUTATION[(col + y) % NOISE_PERIOD] as f32 * (1.0 / 255.0);
    let (col0, col1) = (column(x), column(x + 1));
    let (c00, c10, c01, c11) = (value(col0, y), value(col1, y), value(col0, y + 1), value(col1, y + 1));
    let s = f * f * (Vec2::splat(3.0) - 2.0 * f);
    let bottom = c00 + s.x * (c10 - c00);
    let top = c01 + s.x * (c11 - c01);
    bottom + s.y * (top - bottom)
}

/// Weights of successive octaves of [`fractal_noise`] (each octave doubles the frequency).
const OCTAVE_WEIGHTS: [f32; 3] = [0.5, 0.3, 0.2];

/// `octaves` (1 to 3) octaves of value noise, in `[0, 1]`.
fn fractal_noise(p: Vec2, seed: u32, octaves: usize) -> f32 {
    let weights = &OCTAVE_WEIGHTS[..octaves];
    let mut sum = 0.0;
    let mut frequency = 1.0;
    for (octave, weight) in weights.iter().enumerate() {
        // Not exactly 2: lattices of successive octaves should not line up.
        sum += weight * value_noise(frequency * p, seed.wrapping_add(octave as u32));
        frequency *= 2.03;
    }
    (sum / weights.iter().sum::<f32>()).clamp(0.0, 1.0)
}

/// The fractional part, `x - floor(x)`, in `[0, 1)` also for negative `x` (unlike `f32::fract`);
/// cheaper than `rem_euclid`, which calls `fmodf`.
#[inline]
fn fract(x: f32) -> f32 {
    x - x.floor()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn hsv_primaries() {
        assert!((hsv_to_rgb(0.0, 1.0, 1.0) - Vec3::X).length() < 1e-6);
        assert!((hsv_to_rgb(1.0 / 3.0, 1.0, 1.0) - Vec3::Y).length() < 1e-5);
        assert!((hsv_to_rgb(0.3, 0.0, 0.5) - Vec3::splat(0.5)).length() < 1e-6);
    }

    #[test]
    fn random_textures_stay_in_range_and_vary() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..50 {
            let texture = Texture::random(&mut rng);
            let colors: Vec<Vec3> =
                (0..200).map(|i| texture.color_at(Vec2::new(i as f32 * 0.037, i as f32 * 0.011))).collect();
            for c in &colors {
                assert!(c.min_element() >= 0.0 && c.max_element() <= 1.3, "{c} of {texture:?}");
            }
            let spread = colors.iter().map(|c| (*c - colors[0]).length()).fold(0.0, f32::max);
            assert!(spread > 0.02, "a texture must not be uniform: {texture:?}");
        }
    }

    #[test]
    fn checker_alternates() {
        let mut t = Texture::plain(Vec3::ZERO);
        t.palette[1] = Vec3::ONE;
        t.pattern = Pattern::Checker { cell: 0.5 };
        assert_eq!(t.color_at(Vec2::new(0.25, 0.25)), Vec3::ZERO);
        assert_eq!(t.color_at(Vec2::new(0.75, 0.25)), Vec3::ONE);
        assert_eq!(t.color_at(Vec2::new(-0.25, 0.25)), Vec3::ONE);
    }
}
