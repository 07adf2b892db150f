//! Square crops centred on a pixel and shifted to lie inside the frame (ALGORITHMS.md §5).

use ivp_core::Image;

/// A `size` x `size` window of a frame: columns `left..left + size`, rows `top..top + size`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CropWindow {
    pub left: usize,
    pub top: usize,
    pub size: usize,
}

impl CropWindow {
    /// The window whose pixel `(size / 2, size / 2)` is `centre`, shifted by the least amount that
    /// puts it inside a `frame = (width, height)` frame. Panics if the frame is smaller than `size`.
    pub fn centred_on(centre: (usize, usize), size: usize, frame: (usize, usize)) -> Self {
        assert!(frame.0 >= size && frame.1 >= size, "{size}x{size} crop of a {}x{} frame", frame.0, frame.1);
        let start = |c: usize, extent: usize| c.saturating_sub(size / 2).min(extent - size);
        Self { left: start(centre.0, frame.0), top: start(centre.1, frame.1), size }
    }

    /// Frame pixel `(u, v)` in crop coordinates, if inside.
    pub fn to_crop(&self, (u, v): (usize, usize)) -> Option<(usize, usize)> {
        let inside = (self.left..self.left + self.size).contains(&u) && (self.top..self.top + self.size).contains(&v);
        inside.then(|| (u - self.left, v - self.top))
    }

    /// The window's pixels of `image`.
    pub fn cut<const C: usize>(&self, image: &Image<C>) -> Image<C> {
        image.crop(self.left, self.top, self.size, self.size)
    }

    /// The window's pixels of a row-major per-pixel field of a `width`-wide frame.
    pub fn cut_field<T: Copy>(&self, field: &[T], width: usize) -> Vec<T> {
        let mut out = Vec::with_capacity(self.size * self.size);
        for v in self.top..self.top + self.size {
            out.extend_from_slice(&field[v * width + self.left..v * width + self.left + self.size]);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centred_when_it_fits_and_shifted_inside_otherwise() {
        let frame = (100, 80);
        let inner = CropWindow::centred_on((50, 40), 32, frame);
        assert_eq!((inner.left, inner.top), (34, 24));
        assert_eq!(inner.to_crop((50, 40)), Some((16, 16)));
        let corner = CropWindow::centred_on((2, 79), 32, frame);
        assert_eq!((corner.left, corner.top), (0, 48));
        assert_eq!(corner.to_crop((2, 79)), Some((2, 31)));
        let exact = CropWindow::centred_on((99, 0), 80, frame);
        assert_eq!((exact.left, exact.top), (20, 0));
        let whole = CropWindow::centred_on((7, 7), 80, (80, 80));
        assert_eq!((whole.left, whole.top), (0, 0));
    }

    #[test]
    fn cut_reads_the_window() {
        let image = Image::<1>::from_fn(10, 8, |u, v| [(u + 10 * v) as f32]);
        let window = CropWindow { left: 3, top: 2, size: 4 };
        let crop = window.cut(&image);
        assert_eq!(crop.get(0, 0), [23.0]);
        assert_eq!(crop.get(3, 3), [56.0]);
        let field: Vec<usize> = (0..80).collect();
        assert_eq!(window.cut_field(&field, 10)[5], 34);
    }
}
