//! The nearest known pixel in each of the four directions, for every pixel, in O(pixels).

use rayon::prelude::*;

use crate::geometry::frame::{Direction, Pixel};

/// For every pixel, the nearest known pixel strictly beyond it in each of the four directions.
///
/// Built in O(pixels) once per mask, so that searches from large holes (a frame that is all hole)
/// cost the same as from small ones, and walking from one known pixel to the next known pixel
/// along a direction (skipping holes) is a single lookup.
#[derive(Clone, Debug)]
pub struct NearestKnown {
    width: usize,
    height: usize,
    /// Column of the nearest known pixel to the left, or [`Self::NONE`].
    left: Vec<u32>,
    /// Column of the nearest known pixel to the right, or [`Self::NONE`].
    right: Vec<u32>,
    /// Row of the nearest known pixel above, or [`Self::NONE`].
    up: Vec<u32>,
    /// Row of the nearest known pixel below, or [`Self::NONE`].
    down: Vec<u32>,
}

impl NearestKnown {
    const NONE: u32 = u32::MAX;

    /// Panics if `known.len() != width * height` or a side does not fit in `u32`.
    pub fn new(width: usize, height: usize, known: &[bool]) -> Self {
        assert_eq!(known.len(), width * height, "known mask does not match {width}x{height}");
        assert!(width < Self::NONE as usize && height < Self::NONE as usize, "frame too large");
        let ((left, right), (up, down)) =
            rayon::join(|| Self::along_rows(width, known), || Self::along_columns(width, height, known));
        Self { width, height, left, right, up, down }
    }

    fn along_rows(width: usize, known: &[bool]) -> (Vec<u32>, Vec<u32>) {
        let mut left = vec![Self::NONE; known.len()];
        let mut right = vec![Self::NONE; known.len()];
        let chunk = width.max(1);
        left.par_chunks_mut(chunk).zip(right.par_chunks_mut(chunk)).zip(known.par_chunks(chunk)).for_each(
            |((left, right), known)| {
                let mut last = Self::NONE;
                for u in 0..known.len() {
                    left[u] = last;
                    if known[u] {
                        last = u as u32;
                    }
                }
                last = Self::NONE;
                for u in (0..known.len()).rev() {
                    right[u] = last;
                    if known[u] {
                        last = u as u32;
                    }
                }
            },
        );
        (left, right)
    }

    fn along_columns(width: usize, height: usize, known: &[bool]) -> (Vec<u32>, Vec<u32>) {
        // Each row follows from the one before it (above for `up`, below for `down`): the two
        // sweeps are serial in rows, so they run side by side.
        rayon::join(
            || {
                let mut up = vec![Self::NONE; known.len()];
                for v in 1..height {
                    let (done, row) = up.split_at_mut(v * width);
                    let previous = &done[(v - 1) * width..];
                    let previous_known = &known[(v - 1) * width..v * width];
                    for u in 0..width {
                        row[u] = if previous_known[u] { (v - 1) as u32 } else { previous[u] };
                    }
                }
                up
            },
            || {
                let mut down = vec![Self::NONE; known.len()];
                for v in (0..height.saturating_sub(1)).rev() {
                    let (row, done) = down.split_at_mut((v + 1) * width);
                    let row = &mut row[v * width..];
                    let next_known = &known[(v + 1) * width..(v + 2) * width];
                    for u in 0..width {
                        row[u] = if next_known[u] { (v + 1) as u32 } else { done[u] };
                    }
                }
                down
            },
        )
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The nearest known pixel strictly beyond `p` in direction `dir`.
    #[inline]
    pub fn beyond(&self, p: Pixel, dir: Direction) -> Option<Pixel> {
        let (u, v) = p;
        let i = v * self.width + u;
        match dir {
            Direction::Left | Direction::Right => {
                let col = if dir == Direction::Left { self.left[i] } else { self.right[i] };
                (col != Self::NONE).then_some((col as usize, v))
            }
            Direction::Up | Direction::Down => {
                let row = if dir == Direction::Up { self.up[i] } else { self.down[i] };
                (row != Self::NONE).then_some((u, row as usize))
            }
        }
    }

    /// The nearest known pixels of `p` in the order of [`Direction::ALL`].
    #[inline]
    pub fn around(&self, p: Pixel) -> [Option<Pixel>; 4] {
        Direction::ALL.map(|dir| self.beyond(p, dir))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_known_finds_known_pixels_strictly_beyond() {
        let (w, h) = (7, 5);
        let known: Vec<bool> = (0..w * h).map(|i| i % 3 == 0).collect();
        let nearest = NearestKnown::new(w, h, &known);
        let is_known = |(u, v): Pixel| known[v * w + u];
        for v in 0..h {
            for u in 0..w {
                for dir in Direction::ALL {
                    // Walk one step at a time: the first known pixel met is the answer.
                    let mut walk = dir.step((u, v), w, h);
                    while let Some(q) = walk.filter(|&q| !is_known(q)) {
                        walk = dir.step(q, w, h);
                    }
                    assert_eq!(nearest.beyond((u, v), dir), walk, "({u}, {v}) {dir:?}");
                }
            }
        }
    }
}
