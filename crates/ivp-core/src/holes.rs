//! Holes of a warp, split into new regions and disocclusions (SPEC §4.1).

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
        // First and last known index of every column.
        let mut col_first = vec![usize::MAX; width];
        let mut col_last = vec![0usize; width];
        for v in 0..height {
            for u in 0..width {
                if known[v * width + u] {
                    col_first[u] = col_first[u].min(v);
                    col_last[u] = v;
                }
            }
        }
        let mut classes = vec![PixelClass::Known; width * height];
        for v in 0..height {
            let row = &known[v * width..(v + 1) * width];
            let first = row.iter().position(|&k| k);
            let last = row.iter().rposition(|&k| k);
            for u in 0..width {
                if row[u] {
                    continue;
                }
                let inside_row = matches!((first, last), (Some(a), Some(b)) if a < u && u < b);
                let inside_col = col_first[u] < v && v < col_last[u] && col_first[u] != usize::MAX;
                classes[v * width + u] =
                    if inside_row && inside_col { PixelClass::Disocclusion } else { PixelClass::NewRegion };
            }
        }
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
    fn all_hole_frame_is_all_new_region() {
        let m = HoleMask::classify(4, 4, &[false; 16]);
        assert_eq!(m.count(PixelClass::NewRegion), 16);
    }
}
