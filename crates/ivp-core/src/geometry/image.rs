//! Dense images with a fixed number of interleaved f32 channels.

/// A row-major image of `C` interleaved f32 channels; pixel `(u, v)` is column `u`, row `v`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<const C: usize> {
    width: usize,
    height: usize,
    pixels: Vec<[f32; C]>,
}

/// RGB in `[0, 1]` (sRGB values as stored, not linearised).
pub type RgbImage = Image<3>;
/// Planar depth (camera-space z) in scene units; not finite or `<= 0` means invalid.
pub type DepthMap = Image<1>;
/// Per-pixel 2-D vectors `(a, b)` in pixels: `a` along columns, `b` along rows.
pub type VectorField = Image<2>;

/// An axis-aligned rectangle of pixels: columns `x..x + width`, rows `y..y + height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Rect {
    /// The whole of a `width` x `height` frame.
    pub fn whole(width: usize, height: usize) -> Rect {
        Rect { x: 0, y: 0, width, height }
    }

    pub fn area(&self) -> usize {
        self.width * self.height
    }

    /// The smallest rectangle that holds both.
    pub fn union(&self, other: &Rect) -> Rect {
        let (x, y) = (self.x.min(other.x), self.y.min(other.y));
        let right = (self.x + self.width).max(other.x + other.width);
        let bottom = (self.y + self.height).max(other.y + other.height);
        Rect { x, y, width: right - x, height: bottom - y }
    }
}

impl<const C: usize> Image<C> {
    /// An image filled with zeros.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self::filled(width, height, [0.0; C])
    }

    pub fn filled(width: usize, height: usize, value: [f32; C]) -> Self {
        Self { width, height, pixels: vec![value; width * height] }
    }

    /// Wraps row-major pixels. Panics if `pixels.len() != width * height` (a programming error).
    pub fn from_pixels(width: usize, height: usize, pixels: Vec<[f32; C]>) -> Self {
        assert_eq!(pixels.len(), width * height, "pixel count does not match {width}x{height}");
        Self { width, height, pixels }
    }

    pub fn from_fn(width: usize, height: usize, f: impl Fn(usize, usize) -> [f32; C]) -> Self {
        let pixels = (0..height).flat_map(|v| (0..width).map(move |u| (u, v))).map(|(u, v)| f(u, v)).collect();
        Self { width, height, pixels }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    pub fn same_size<const D: usize>(&self, other: &Image<D>) -> bool {
        self.width == other.width && self.height == other.height
    }

    #[inline]
    pub fn index(&self, u: usize, v: usize) -> usize {
        v * self.width + u
    }

    #[inline]
    pub fn get(&self, u: usize, v: usize) -> [f32; C] {
        self.pixels[v * self.width + u]
    }

    #[inline]
    pub fn set(&mut self, u: usize, v: usize, value: [f32; C]) {
        let i = v * self.width + u;
        self.pixels[i] = value;
    }

    pub fn pixels(&self) -> &[[f32; C]] {
        &self.pixels
    }

    pub fn pixels_mut(&mut self) -> &mut [[f32; C]] {
        &mut self.pixels
    }

    pub fn into_pixels(self) -> Vec<[f32; C]> {
        self.pixels
    }

    /// Row `v` as a slice.
    pub fn row(&self, v: usize) -> &[[f32; C]] {
        &self.pixels[v * self.width..(v + 1) * self.width]
    }

    /// The `width` x `height` window whose top-left pixel is `(left, top)`. Panics if it does not
    /// lie inside the image.
    pub fn crop(&self, left: usize, top: usize, width: usize, height: usize) -> Self {
        assert!(left + width <= self.width && top + height <= self.height, "crop outside the image");
        let mut pixels = Vec::with_capacity(width * height);
        for v in top..top + height {
            pixels.extend_from_slice(&self.row(v)[left..left + width]);
        }
        Self::from_pixels(width, height, pixels)
    }

    /// The pixels flattened channel-interleaved (`[r, g, b, r, g, b, ...]`).
    pub fn as_flat(&self) -> &[f32] {
        self.pixels.as_flattened()
    }

    /// Rounds every channel to the 8-bit grid (`round(x * 255) / 255`, clamped to `[0, 1]`),
    /// as every prediction is before it is scored (ALGORITHMS.md §7).
    pub fn quantized_to_8bit(&self) -> Self {
        let mut out = self.clone();
        for p in &mut out.pixels {
            for c in p.iter_mut() {
                *c = to_u8(*c) as f32 / 255.0;
            }
        }
        out
    }
}

impl Image<1> {
    /// The single channel at `(u, v)`.
    #[inline]
    pub fn at(&self, u: usize, v: usize) -> f32 {
        self.pixels[v * self.width + u][0]
    }

    /// Wraps a plain row-major slice of values.
    pub fn from_values(width: usize, height: usize, values: Vec<f32>) -> Self {
        Self::from_pixels(width, height, values.into_iter().map(|x| [x]).collect())
    }
}

/// An f32 in `[0, 1]` to its nearest 8-bit value (NaN maps to 0).
#[inline]
pub fn to_u8(x: f32) -> u8 {
    if x.is_nan() {
        0
    } else {
        (x.clamp(0.0, 1.0) * 255.0).round() as u8
    }
}

/// True when a depth value can be warped: finite and strictly positive.
#[inline]
pub fn is_valid_depth(z: f32) -> bool {
    z.is_finite() && z > 0.0
}
