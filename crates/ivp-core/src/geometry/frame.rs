//! Frames as the later stages see them: a rendered view, pixels, and the four search directions.

use crate::geometry::camera::WorldToCamera;
use crate::geometry::image::{DepthMap, RgbImage};

/// A rendered frame as an infiller sees it.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    pub image: &'a RgbImage,
    pub depth: &'a DepthMap,
    pub pose: &'a WorldToCamera,
}

/// A pixel `(u, v)`: column, row.
pub type Pixel = (usize, usize);

/// The four search directions, in the order that breaks every tie in this crate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    Left,
    Right,
    Up,
    Down,
}

impl Direction {
    /// Left, right, up, down: the tie-break order.
    pub const ALL: [Direction; 4] = [Direction::Left, Direction::Right, Direction::Up, Direction::Down];

    /// The neighbour one pixel away in this direction, if it is inside a `width` x `height` frame.
    #[inline]
    pub fn step(self, (u, v): Pixel, width: usize, height: usize) -> Option<Pixel> {
        match self {
            Direction::Left => u.checked_sub(1).map(|u| (u, v)),
            Direction::Right => (u + 1 < width).then_some((u + 1, v)),
            Direction::Up => v.checked_sub(1).map(|v| (u, v)),
            Direction::Down => (v + 1 < height).then_some((u, v + 1)),
        }
    }
}
