//! Holes of a warp, split into new regions and disocclusions (ALGORITHMS.md §4.1).

use rayon::prelude::*;

/// Rows per parallel task when gathering the known extent of each column.
const CLASSIFY_BAND_ROWS: usize = 64;

/// What a pixel of a warped frame is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum PixelClass {
    /// Some source pixel landed here.
    Known = 0,
    /// A hole at the frame border: content entering the view.
    NewRegion = 1,
    /// A hole with known pixels left, right, above and below: background uncovered behind an object.
    Disocclusion = 2,
}

/// The pixels within `radius` (Chebyshev distance: a square of side `2 radius + 1`) of a pixel
/// marked in `marked` (row-major, `width x height`).
pub fn within_reach(marked: &[bool], width: usize, height: usize, radius: usize) -> Vec<bool> {
    assert_eq!(marked.len(), width * height, "mask does not match {width}x{height}");
    // Along the rows, then along the columns: each a running count of marks in the window.
    let spread = |line: &[bool], out: &mut [bool]| {
        let n = line.len();
        let mut count = line[..radius.min(n)].iter().filter(|&&m| m).count();
        for (i, o) in out.iter_mut().enumerate() {
            if i + radius < n && line[i + radius] {
                count += 1;
            }
            *o = count > 0;
            if i >= radius && line[i - radius] {
                count -= 1;
            }
        }
    };
    let mut rows = vec![false; marked.len()];
    if width == 0 {
        return rows;
    }
    rows.par_chunks_mut(width).zip(marked.par_chunks(width)).for_each(|(out, line)| spread(line, out));
    // Down the columns, all of them at once: a count per column of the marks in the window of
    // rows, slid one row at a time (a column at a time strides through memory, 3x slower).
    let mut out = vec![false; marked.len()];
    let mut counts = vec![0u32; width];
    let row = |v: usize| &rows[v * width..][..width];
    let enter = |counts: &mut [u32], line: &[bool]| counts.iter_mut().zip(line).for_each(|(c, &m)| *c += u32::from(m));
    let leave = |counts: &mut [u32], line: &[bool]| counts.iter_mut().zip(line).for_each(|(c, &m)| *c -= u32::from(m));
    (0..radius.min(height)).for_each(|v| enter(&mut counts, row(v)));
    for (v, out) in out.chunks_exact_mut(width).enumerate() {
        if v + radius < height {
            enter(&mut counts, row(v + radius));
        }
        out.iter_mut().zip(&counts).for_each(|(o, &c)| *o = c > 0);
        if v >= radius {
            leave(&mut counts, row(v - radius));
        }
    }
    out
}

/// Per-pixel classes of a warped frame.
#[derive(Clone, Debug, PartialEq)]
pub struct HoleMask {
    width: usize,
    height: usize,
    classes: Vec<PixelClass>,
}

impl HoleMask {
    /// Classifies the holes of a warp from its known mask *(ref rule)*: a hole pixel is a
    /// disocclusion when its row has a known pixel on both sides and its column has one above and
    /// below; every other hole pixel is a new region.
    pub fn classify(width: usize, height: usize, known: &[bool]) -> Self {
        assert_eq!(known.len(), width * height);
        if known.is_empty() {
            return Self { width, height, classes: Vec::new() };
        }
        assert!(height < u32::MAX as usize, "a frame of {height} rows is too tall to classify");
        // First and last known row of every column (first > last if none), over bands of rows in
        // parallel, then merged. As u32, so that the per-pixel loops below vectorise.
        let none = || (vec![u32::MAX; width], vec![0u32; width]);
        let (col_first, col_last) = known
            .par_chunks(CLASSIFY_BAND_ROWS * width)
            .enumerate()
            .map(|(b, band)| {
                let (mut first, mut last) = none();
                for (r, row) in band.chunks_exact(width).enumerate() {
                    let v = (b * CLASSIFY_BAND_ROWS + r) as u32;
                    for ((first, last), &k) in first.iter_mut().zip(&mut last).zip(row) {
                        (*first, *last) = if k { ((*first).min(v), v) } else { (*first, *last) };
                    }
                }
                (first, last)
            })
            .reduce(none, |(mut first, mut last), (other_first, other_last)| {
                first.iter_mut().zip(other_first).for_each(|(a, b)| *a = (*a).min(b));
                last.iter_mut().zip(other_last).for_each(|(a, b)| *a = (*a).max(b));
                (first, last)
            });
        let mut classes = vec![PixelClass::Known; width * height];
        classes.par_chunks_mut(width).zip(known.par_chunks(width)).enumerate().with_min_len(8).for_each(
            |(v, (classes, row))| {
                let (Some(first), Some(last)) = (row.iter().position(|&k| k), row.iter().rposition(|&k| k)) else {
                    classes.fill(PixelClass::NewRegion);
                    return;
                };
                let (first, last, v) = (first as u32, last as u32, v as u32);
                let columns = col_first.iter().zip(&col_last);
                for (u, ((class, &k), (&above, &below))) in classes.iter_mut().zip(row).zip(columns).enumerate() {
                    let u = u as u32;
                    let enclosed = (first < u) & (u < last) & (above < v) & (v < below);
                    *class = match (k, enclosed) {
                        (true, _) => PixelClass::Known,
                        (false, true) => PixelClass::Disocclusion,
                        (false, false) => PixelClass::NewRegion,
                    };
                }
            },
        );
        Self { width, height, classes }
    }

    /// A mask in which every pixel has the given class.
    pub fn uniform(width: usize, height: usize, class: PixelClass) -> Self {
        Self { width, height, classes: vec![class; width * height] }
    }

    pub fn from_classes(width: usize, height: usize, classes: Vec<PixelClass>) -> Self {
        assert_eq!(classes.len(), width * height);
        Self { width, height, classes }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn classes(&self) -> &[PixelClass] {
        &self.classes
    }

    #[inline]
    pub fn class(&self, u: usize, v: usize) -> PixelClass {
        self.classes[v * self.width + u]
    }

    #[inline]
    pub fn is_known(&self, u: usize, v: usize) -> bool {
        self.class(u, v) == PixelClass::Known
    }

    #[inline]
    pub fn is_disocclusion(&self, u: usize, v: usize) -> bool {
        self.class(u, v) == PixelClass::Disocclusion
    }

    /// `true` for known pixels, row-major.
    pub fn known(&self) -> Vec<bool> {
        self.classes.iter().map(|&c| c == PixelClass::Known).collect()
    }

    /// `true` for disocclusion pixels, row-major.
    pub fn disocclusions(&self) -> Vec<bool> {
        self.classes.iter().map(|&c| c == PixelClass::Disocclusion).collect()
    }

    /// The row-major indices of the pixels of `class`, in order.
    pub fn indices_of(&self, class: PixelClass) -> Vec<usize> {
        // Row by row, each a plain loop (a parallel filter over the indices compiled to a loop
        // that copied its state through memory at every pixel: 10 ms for a 1080p frame).
        let w = self.width.max(1);
        let rows: Vec<Vec<usize>> = self
            .classes
            .par_chunks(w)
            .enumerate()
            .map(|(v, row)| {
                let mut indices = Vec::new();
                for (u, &c) in row.iter().enumerate() {
                    if c == class {
                        indices.push(v * w + u);
                    }
                }
                indices
            })
            .collect();
        rows.concat()
    }

    pub fn count(&self, class: PixelClass) -> usize {
        self.classes.iter().filter(|&&c| c == class).count()
    }

    /// The "holes" image of the tools: 255 = disocclusion, 128 = new region, 0 = known.
    pub fn to_gray8(&self) -> Vec<u8> {
        self.classes
            .iter()
            .map(|c| match c {
                PixelClass::Known => 0,
                PixelClass::NewRegion => 128,
                PixelClass::Disocclusion => 255,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn indices_of_a_class_are_its_pixels_in_order() {
        for (w, h) in [(7, 5), (1, 9), (9, 1), (0, 0), (300, 4)] {
            let classes: Vec<PixelClass> = (0..w * h)
                .map(|i| match (i * 7 + i / 3) % 5 {
                    0 => PixelClass::Disocclusion,
                    1 => PixelClass::NewRegion,
                    _ => PixelClass::Known,
                })
                .collect();
            let mask = HoleMask::from_classes(w, h, classes.clone());
            for class in [PixelClass::Disocclusion, PixelClass::NewRegion, PixelClass::Known] {
                let expected: Vec<usize> = (0..w * h).filter(|&i| classes[i] == class).collect();
                assert_eq!(mask.indices_of(class), expected, "{w}x{h} {class:?}");
            }
        }
    }

    #[test]
    fn within_reach_matches_a_brute_force_search() {
        for (w, h, radius) in [(1, 1, 0), (1, 1, 3), (7, 5, 0), (7, 5, 1), (13, 9, 2), (13, 9, 20), (40, 3, 4)] {
            let marked: Vec<bool> = (0..w * h).map(|i| (i * 37 + 11) % 23 == 0).collect();
            let got = within_reach(&marked, w, h, radius);
            for v in 0..h {
                for u in 0..w {
                    let want = (0..h).any(|y| {
                        (0..w).any(|x| marked[y * w + x] && u.abs_diff(x) <= radius && v.abs_diff(y) <= radius)
                    });
                    assert_eq!(got[v * w + u], want, "{w}x{h} radius {radius} at ({u}, {v})");
                }
            }
        }
        assert!(within_reach(&[], 0, 4, 2).is_empty());
    }

    use super::*;

    #[test]
    fn enclosed_hole_is_disocclusion_and_border_hole_is_new_region() {
        // 5x3, known everywhere but (2,1) (enclosed) and column 4 of row 1 (border).
        let mut known = vec![true; 15];
        known[5 + 2] = false;
        known[5 + 4] = false;
        let m = HoleMask::classify(5, 3, &known);
        assert_eq!(m.class(2, 1), PixelClass::Disocclusion);
        assert_eq!(m.class(4, 1), PixelClass::NewRegion);
        assert_eq!(m.count(PixelClass::Known), 13);
    }

    #[test]
    fn the_holes_image_codes_each_class_by_its_grey() {
        let classes = [PixelClass::Known, PixelClass::Disocclusion, PixelClass::NewRegion, PixelClass::Known];
        let mask = HoleMask::from_classes(2, 2, classes.to_vec());
        assert_eq!(mask.to_gray8(), [0, 255, 128, 0]);
        assert!(HoleMask::from_classes(0, 3, Vec::new()).to_gray8().is_empty());
    }

    #[test]
    fn all_hole_frame_is_all_new_region() {
        let m = HoleMask::classify(4, 4, &[false; 16]);
        assert_eq!(m.count(PixelClass::NewRegion), 16);
    }

    /// The rule of ALGORITHMS.md §4.1 pixel by pixel, straight from its wording.
    fn classify_naive(w: usize, h: usize, known: &[bool]) -> Vec<PixelClass> {
        let k = |u: usize, v: usize| known[v * w + u];
        (0..w * h)
            .map(|i| {
                let (u, v) = (i % w, i / w);
                if k(u, v) {
                    PixelClass::Known
                } else if (0..u).any(|x| k(x, v))
                    && (u + 1..w).any(|x| k(x, v))
                    && (0..v).any(|y| k(u, y))
                    && (v + 1..h).any(|y| k(u, y))
                {
                    PixelClass::Disocclusion
                } else {
                    PixelClass::NewRegion
                }
            })
            .collect()
    }

    #[test]
    fn classify_follows_the_rule_on_random_masks() {
        let mut state = 12345u64;
        let mut random = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as u32
        };
        // Taller than a band of the column pass, and degenerate sizes.
        for (w, h) in [(37, CLASSIFY_BAND_ROWS * 2 + 9), (1, 1), (3, 2), (1, 7), (7, 1), (0, 0), (0, 4), (4, 0)] {
            for holes_in_100 in [0, 5, 50, 95, 100] {
                let known: Vec<bool> = (0..w * h).map(|_| random() % 100 >= holes_in_100).collect();
                let want = classify_naive(w, h, &known);
                for threads in [1, 3] {
                    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                    let got = pool.install(|| HoleMask::classify(w, h, &known));
                    assert_eq!(got.classes(), want, "{w}x{h}, {holes_in_100}% holes, {threads} threads");
                }
            }
        }
    }
}
