//! The nearest known pixel in each of the four directions, for every pixel.

use rayon::prelude::*;

use crate::geometry::frame::{Direction, Pixel};

/// For every pixel, the nearest known pixel strictly beyond it in each of the four directions.
///
/// It keeps the runs of unknown pixels of every row and every column, so that a lookup is one
/// binary search among the runs of one line, whatever the size of the hole it starts in (a frame
/// that is all hole costs the same as one small hole), and walking from one known pixel to the
/// next known pixel along a direction (skipping holes) is a single lookup. Building it reads the
/// mask once and keeps memory in proportion to the runs: holes are a small part of a frame, and
/// tables of the whole frame would cost more to fill than every lookup together.
#[derive(Clone, Debug)]
pub struct NearestKnown {
    width: usize,
    height: usize,
    /// Runs of unknown pixels along each row (positions are columns).
    rows: Runs,
    /// Runs of unknown pixels along each column (positions are rows).
    columns: Runs,
    /// The mask itself: a known neighbour, the common case of walks from known pixels, needs no
    /// search.
    known: Vec<bool>,
}

/// The runs of unknown pixels of some lines of equal length: for each line, disjoint half-open
/// ranges `start..end` of positions, in increasing order.
#[derive(Clone, Debug, Default)]
struct Runs {
    /// Runs of line `l` are `runs[offsets[l]..offsets[l + 1]]`.
    offsets: Vec<usize>,
    runs: Vec<(u32, u32)>,
    /// Positions per line.
    length: usize,
}

impl Runs {
    /// From the runs of each line, in line order.
    fn from_lines(lines: Vec<Vec<(u32, u32)>>, length: usize) -> Self {
        let mut offsets = Vec::with_capacity(lines.len() + 1);
        offsets.push(0);
        let mut runs = Vec::with_capacity(lines.iter().map(Vec::len).sum());
        for line in lines {
            runs.extend(line);
            offsets.push(runs.len());
        }
        Self { offsets, runs, length }
    }

    /// The run of line `line` that holds position `x`, if `x` is not known.
    #[inline]
    fn run_at(&self, line: usize, x: usize) -> Option<(u32, u32)> {
        let runs = &self.runs[self.offsets[line]..self.offsets[line + 1]];
        let after = runs.partition_point(|&(start, _)| start as usize <= x);
        let &(start, end) = runs[..after].last()?;
        (x < end as usize).then_some((start, end))
    }

    /// The nearest known position strictly before `x` on `line`.
    #[inline]
    fn before(&self, line: usize, x: usize) -> Option<usize> {
        let previous = x.checked_sub(1)?;
        match self.run_at(line, previous) {
            None => Some(previous),
            Some((start, _)) => (start as usize).checked_sub(1),
        }
    }

    /// The nearest known position strictly after `x` on `line`.
    #[inline]
    fn after(&self, line: usize, x: usize) -> Option<usize> {
        let next = x + 1;
        if next >= self.length {
            return None;
        }
        match self.run_at(line, next) {
            None => Some(next),
            Some((_, end)) => ((end as usize) < self.length).then_some(end as usize),
        }
    }
}

impl NearestKnown {
    /// Panics if `known.len() != width * height` or a side does not fit in `u32`.
    pub fn new(width: usize, height: usize, known: &[bool]) -> Self {
        assert_eq!(known.len(), width * height, "known mask does not match {width}x{height}");
        assert!(width < u32::MAX as usize && height < u32::MAX as usize, "frame too large");
        let (rows, columns) =
            rayon::join(|| Self::runs_of_rows(width, known), || Self::runs_of_columns(width, height, known));
        Self { width, height, rows, columns, known: known.to_vec() }
    }

    fn runs_of_rows(width: usize, known: &[bool]) -> Runs {
        let lines = known
            .par_chunks(width.max(1))
            .map(|row| {
                // A byte search for the next `false` (0) and `true` (1): a loop over the bools
                // that stops at the first one does not vectorise.
                let bytes = as_bytes(row);
                let mut runs = Vec::new();
                let mut u = 0;
                while let Some(start) = memchr::memchr(0, &bytes[u..]).map(|i| u + i) {
                    let end = memchr::memchr(1, &bytes[start..]).map_or(row.len(), |i| start + i);
                    runs.push((start as u32, end as u32));
                    u = end;
                }
                runs
            })
            .collect();
        Runs::from_lines(lines, width)
    }

    /// Bands of columns in parallel, each read row by row (the mask's order in memory).
    fn runs_of_columns(width: usize, height: usize, known: &[bool]) -> Runs {
        const BAND: usize = 64;
        let bands: Vec<Vec<Vec<(u32, u32)>>> = (0..width.div_ceil(BAND))
            .into_par_iter()
            .map(|band| {
                let columns = band * BAND..((band + 1) * BAND).min(width);
                let mut runs = vec![Vec::new(); columns.len()];
                let mut open: Vec<Option<u32>> = vec![None; columns.len()];
                for v in 0..height {
                    let row = &known[v * width..][columns.clone()];
                    for ((&k, open), runs) in row.iter().zip(&mut open).zip(&mut runs) {
                        match (k, *open) {
                            (false, None) => *open = Some(v as u32),
                            (true, Some(start)) => {
                                runs.push((start, v as u32));
                                *open = None;
                            }
                            _ => {}
                        }
                    }
                }
                for (open, runs) in open.into_iter().zip(&mut runs) {
                    if let Some(start) = open {
                        runs.push((start, height as u32));
                    }
                }
                runs
            })
            .collect();
        Runs::from_lines(bands.into_iter().flatten().collect(), height)
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
        debug_assert!(u < self.width && v < self.height, "({u}, {v}) is outside the frame");
        let neighbour = match dir {
            Direction::Left => u.checked_sub(1).map(|u| (u, v)),
            Direction::Right => (u + 1 < self.width).then_some((u + 1, v)),
            Direction::Up => v.checked_sub(1).map(|v| (u, v)),
            Direction::Down => (v + 1 < self.height).then_some((u, v + 1)),
        }?;
        if self.known[neighbour.1 * self.width + neighbour.0] {
            return Some(neighbour);
        }
        match dir {
            Direction::Left => self.rows.before(v, u).map(|u| (u, v)),
            Direction::Right => self.rows.after(v, u).map(|u| (u, v)),
            Direction::Up => self.columns.before(u, v).map(|v| (u, v)),
            Direction::Down => self.columns.after(u, v).map(|v| (u, v)),
        }
    }

    /// The nearest known pixels of `p` in the order of [`Direction::ALL`].
    #[inline]
    pub fn around(&self, p: Pixel) -> [Option<Pixel>; 4] {
        Direction::ALL.map(|dir| self.beyond(p, dir))
    }
}

/// The bytes of a mask: `false` is 0 and `true` is 1.
fn as_bytes(mask: &[bool]) -> &[u8] {
    // SAFETY: a bool is one byte holding 0 or 1, so any slice of bools is a valid slice of bytes
    // of the same length; the borrow keeps the bools alive and unchanged.
    unsafe { std::slice::from_raw_parts(mask.as_ptr().cast::<u8>(), mask.len()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every lookup of `known` against a walk of one pixel at a time.
    fn check_against_walks(w: usize, h: usize, known: &[bool]) {
        let nearest = NearestKnown::new(w, h, known);
        let is_known = |(u, v): Pixel| known[v * w + u];
        for v in 0..h {
            for u in 0..w {
                for dir in Direction::ALL {
                    // Walk one step at a time: the first known pixel met is the answer.
                    let mut walk = dir.step((u, v), w, h);
                    while let Some(q) = walk.filter(|&q| !is_known(q)) {
                        walk = dir.step(q, w, h);
                    }
                    assert_eq!(nearest.beyond((u, v), dir), walk, "{w}x{h}: ({u}, {v}) {dir:?}");
                }
            }
        }
    }

    #[test]
    fn nearest_known_finds_known_pixels_strictly_beyond() {
        let (w, h) = (7, 5);
        check_against_walks(w, h, &(0..w * h).map(|i| i % 3 == 0).collect::<Vec<_>>());
    }

    #[test]
    fn runs_at_every_border_and_of_every_length() {
        // Holes touching each side and corner, long and one pixel wide, and bands wider than the
        // 64 columns that the column runs are built in.
        let (w, h) = (150, 9);
        let known: Vec<bool> = (0..w * h)
            .map(|i| {
                let (u, v) = (i % w, i / w);
                !(u < 3 || u >= w - 2 || v == 0 || v == h - 1 || (60..70).contains(&u) || (u * 7 + v * 3) % 11 == 0)
            })
            .collect();
        check_against_walks(w, h, &known);
    }

    #[test]
    fn all_hole_no_hole_and_single_lines() {
        for (w, h) in [(5, 4), (1, 6), (6, 1), (1, 1)] {
            check_against_walks(w, h, &vec![false; w * h]);
            check_against_walks(w, h, &vec![true; w * h]);
            check_against_walks(w, h, &(0..w * h).map(|i| i % 2 == 1).collect::<Vec<_>>());
        }
        // An empty frame builds and has nothing to look up.
        let empty = NearestKnown::new(0, 0, &[]);
        assert_eq!((empty.width(), empty.height()), (0, 0));
    }

    #[test]
    fn memory_follows_the_runs_not_the_frame() {
        let (w, h) = (1920, 1080);
        let mut known = vec![true; w * h];
        known[500 * w + 700..500 * w + 720].iter_mut().for_each(|k| *k = false);
        let nearest = NearestKnown::new(w, h, &known);
        assert_eq!(nearest.rows.runs.len(), 1);
        assert_eq!(nearest.columns.runs.len(), 20);
        assert_eq!(nearest.beyond((710, 500), Direction::Left), Some((699, 500)));
        assert_eq!(nearest.beyond((710, 500), Direction::Right), Some((720, 500)));
        assert_eq!(nearest.beyond((710, 500), Direction::Up), Some((710, 499)));
        assert_eq!(nearest.beyond((710, 500), Direction::Down), Some((710, 501)));
    }
}
