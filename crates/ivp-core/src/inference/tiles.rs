//! The plan of sparse inference: the network runs only on tiles of the frame whose core holds
//! pixels to predict, each read with a margin of context around it ([`plan_tiles`];
//! [`super::predictor`] runs them).
//!
//! Tiles sit on a grid of `core`-sized cells anchored at the frame's top-left corner, and `core`
//! and `margin` are multiples of 16, so every tile starts on a multiple of 16: the U-Net's four
//! stride-2 levels then sample the tile on the same grid as the whole frame, and a tile clipped
//! at the frame's border sees the same zero padding there as a dense pass. What differs from a
//! dense pass is only the context cut at the margin: a cell's vectors agree with the dense ones
//! as far as the margin covers what the network looks at (PERFORMANCE.md has the measurements
//! behind [`TileShape::DEFAULT`]).

use std::collections::BTreeMap;

use crate::geometry::Rect;

/// Tiles start on multiples of this: the U-Net halves its maps four times.
pub const TILE_ALIGN: usize = 16;

/// The shape of the tiles of sparse inference, in pixels of the frame as given (a frame shrunk
/// before the network sees it reads tiles of [`TileShape::shrunk_by`] its factor).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileShape {
    /// Side of the cells whose vectors a tile keeps.
    pub core: usize,
    /// Context read on every side of the core (clipped at the frame's border).
    pub margin: usize,
}

impl TileShape {
    /// Cells of 32 pixels with 32 pixels of context, in pixels of the frame as given: at 320x240
    /// the vectors agree with a dense pass within 0.5 px at 99.9% of the disocclusion pixels; at
    /// 1080p, shrunk by 2, the network reads cells of 16 with 16 of context, half the pixels of
    /// 32 and 32 there, for the same D-MSE over three seeds on the Blender clips (PERFORMANCE.md,
    /// "Choosing the tile shape").
    pub const DEFAULT: TileShape = TileShape { core: 32, margin: 32 };

    /// A shape whose core (at least 16) and margin are multiples of [`TILE_ALIGN`].
    pub fn new(core: usize, margin: usize) -> Result<Self, String> {
        if core == 0 || !core.is_multiple_of(TILE_ALIGN) || !margin.is_multiple_of(TILE_ALIGN) {
            return Err(format!(
                "tile core {core} and margin {margin} must be multiples of {TILE_ALIGN} (core at least {TILE_ALIGN})"
            ));
        }
        Ok(Self { core, margin })
    }
}

impl TileShape {
    /// This shape in pixels of the frame shrunk by `factor`: each side divided by it and rounded
    /// up to a multiple of [`TILE_ALIGN`] (the core to at least one).
    pub fn shrunk_by(self, factor: usize) -> TileShape {
        let shrink = |side: usize| side.div_ceil(factor.max(1)).next_multiple_of(TILE_ALIGN);
        TileShape { core: shrink(self.core).max(TILE_ALIGN), margin: shrink(self.margin) }
    }
}

impl Default for TileShape {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the network reads (`input`), and the cells inside it whose vectors are kept (`cores`):
/// each core lies inside `input` with `margin` pixels of context on every side the frame allows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tile {
    pub input: Rect,
    pub cores: Vec<Rect>,
}

/// The tiles of a `width` x `height` frame that cover every cell holding a `marked` pixel.
///
/// Each such cell (`core` pixels on a side) needs itself plus `margin` pixels around it. Cells
/// whose needs overlap or touch form a group. A group is cut in two at the median of its cells
/// along the longer side of its needs' bounding box, each half is planned the same way, and the
/// halves' tiles are kept when they read fewer pixels together than the box; otherwise the box is
/// one tile. Holes are thin slivers along object edges: a sliver stays one thin box, which saves
/// the margins that neighbouring cells would read twice, while the slivers of a frame with holes
/// everywhere join into one group whose box would be the whole frame, and the cuts keep the empty
/// space between them out. Tiles are in row-major order of their first cell; cores in row-major
/// order.
pub fn plan_tiles(width: usize, height: usize, marked: &[bool], shape: TileShape) -> Vec<Tile> {
    assert_eq!(marked.len(), width * height, "mask does not match {width}x{height}");
    let (columns, rows) = (width.div_ceil(shape.core), height.div_ceil(shape.core));
    let mut active = vec![false; columns * rows];
    for (v, row) in marked.chunks_exact(width.max(1)).enumerate() {
        let cells = &mut active[(v / shape.core) * columns..][..columns];
        for (u, _) in row.iter().enumerate().filter(|(_, &m)| m) {
            cells[u / shape.core] = true;
        }
    }
    let cells: Vec<usize> = (0..rows * columns).filter(|&i| active[i]).collect();
    let core_of = |cell: usize| {
        let (x, y) = ((cell % columns) * shape.core, (cell / columns) * shape.core);
        Rect { x, y, width: shape.core.min(width - x), height: shape.core.min(height - y) }
    };
    let need_of = |core: Rect| {
        let span = |start: usize, len: usize, limit: usize| {
            let (lo, hi) = (start.saturating_sub(shape.margin), (start + len + shape.margin).min(limit));
            (lo, hi - lo)
        };
        let ((x, w), (y, h)) = (span(core.x, core.width, width), span(core.y, core.height, height));
        Rect { x, y, width: w, height: h }
    };

    // Group cells whose needs overlap or touch: within `reach` cells of each other.
    let reach = 1 + 2 * shape.margin / shape.core;
    let mut group = UnionFind::new(cells.len());
    let index_of: std::collections::HashMap<usize, usize> = cells.iter().enumerate().map(|(i, &c)| (c, i)).collect();
    for (i, &cell) in cells.iter().enumerate() {
        let (cx, cy) = (cell % columns, cell / columns);
        for ny in cy..=(cy + reach).min(rows - 1) {
            for nx in cx.saturating_sub(reach)..=(cx + reach).min(columns - 1) {
                if let Some(&j) = index_of.get(&(ny * columns + nx)) {
                    if j > i {
                        group.join(i, j);
                    }
                }
            }
        }
    }
    let mut members: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for i in 0..cells.len() {
        members.entry(group.root(i)).or_default().push(i);
    }
    let mut groups: Vec<Vec<usize>> = members.into_values().collect();
    groups.sort_by_key(|g| g[0]);

    let mut tiles = Vec::new();
    for g in groups {
        let mut cores: Vec<Rect> = g.iter().map(|&i| core_of(cells[i])).collect();
        partition(&mut cores, &need_of, &mut tiles);
    }
    let row_major = |r: &Rect| (r.y, r.x);
    tiles.sort_by_key(|t| row_major(&t.cores[0]));
    tiles
}

/// Tiles for `cores` (one group): the cores are cut in two at the median of their positions
/// along the longer side of their needs' bounding box, each side is planned the same way, and
/// the two sides' tiles are kept when they read fewer pixels together than the bounding box,
/// else the box is one tile. Cores are in row-major order within a tile. Returns the pixels read.
///
/// A single cut cannot show that a ring of slivers is cheaper as four thin boxes (either side of
/// any cut still spans the ring), so the sides are planned before they are compared.
fn partition(cores: &mut [Rect], need_of: &impl Fn(Rect) -> Rect, tiles: &mut Vec<Tile>) -> usize {
    let whole = cores.iter().map(|&c| need_of(c)).reduce(|a, b| a.union(&b)).expect("a group has cores");
    let one_tile = |cores: &[Rect], tiles: &mut Vec<Tile>| {
        let mut cores = cores.to_vec();
        cores.sort_by_key(|r| (r.y, r.x));
        tiles.push(Tile { input: whole, cores });
        whole.area()
    };
    // Cut between two distinct positions along the longer side (else the other), nearest the
    // middle (the later one on a tie).
    let mut cut = None;
    for along_columns in [whole.width >= whole.height, whole.width < whole.height] {
        let position = |r: &Rect| if along_columns { (r.x, r.y) } else { (r.y, r.x) };
        cores.sort_by_key(position);
        let middle = cores.len() / 2;
        cut = (1..cores.len())
            .filter(|&k| position(&cores[k - 1]).0 != position(&cores[k]).0)
            .min_by_key(|&k| (k.abs_diff(middle), std::cmp::Reverse(k)));
        if cut.is_some() {
            break;
        }
    }
    let Some(k) = cut else { return one_tile(cores, tiles) };
    let first = tiles.len();
    let (left, right) = cores.split_at_mut(k);
    let pixels = partition(left, need_of, tiles) + partition(right, need_of, tiles);
    if pixels < whole.area() {
        return pixels;
    }
    tiles.truncate(first);
    one_tile(cores, tiles)
}

/// Disjoint sets of `0..n`, for grouping cells.
struct UnionFind(Vec<usize>);

impl UnionFind {
    fn new(n: usize) -> Self {
        Self((0..n).collect())
    }

    fn root(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }

    /// Joins the sets of `a` and `b`; the smaller root represents both (a fixed choice).
    fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.root(a), self.root(b));
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        self.0[hi] = lo;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn marks(width: usize, height: usize, pixels: &[(usize, usize)]) -> Vec<bool> {
        let mut marked = vec![false; width * height];
        for &(u, v) in pixels {
            marked[v * width + u] = true;
        }
        marked
    }

    #[test]
    fn tiles_cover_marked_cells_and_clip_at_borders_and_corners() {
        let (w, h) = (100, 70);
        let shape = TileShape::new(32, 16).unwrap();
        let tiles = plan_tiles(w, h, &marks(w, h, &[(0, 0), (99, 69), (40, 35), (41, 36)]), shape);
        let rect = |x, y, width, height| Rect { x, y, width, height };
        // One group (within two cells of each other), whose bounding box (100x70) reads more
        // than the three cells' needs apart.
        assert_eq!(
            tiles,
            [
                Tile { cores: vec![rect(0, 0, 32, 32)], input: rect(0, 0, 48, 48) },
                Tile { cores: vec![rect(32, 32, 32, 32)], input: rect(16, 16, 64, 54) },
                Tile { cores: vec![rect(96, 64, 4, 6)], input: rect(80, 48, 20, 22) },
            ]
        );
        assert!(tiles.iter().all(|t| t.input.x % TILE_ALIGN == 0 && t.input.y % TILE_ALIGN == 0));
        assert!(plan_tiles(w, h, &vec![false; w * h], shape).is_empty());
        // A vertical sliver: nine cells in a column, read as one thin tile.
        let (w, h) = (200, 200);
        let sliver: Vec<(usize, usize)> = (20..150).flat_map(|v| (50..56).map(move |u| (u, v))).collect();
        let tiles = plan_tiles(w, h, &marks(w, h, &sliver), TileShape::new(16, 16).unwrap());
        assert_eq!(tiles.len(), 1);
        assert_eq!(tiles[0].input, rect(32, 0, 48, 176));
        assert_eq!(tiles[0].cores, (1..=9).map(|r| rect(48, 16 * r, 16, 16)).collect::<Vec<_>>());
        assert!(TileShape::new(24, 16).is_err() && TileShape::new(32, 8).is_err() && TileShape::new(0, 0).is_err());
    }

    #[test]
    fn a_ring_of_holes_is_cut_into_its_sides() {
        // The outline of a square: one group of cells whose bounding box is nearly the frame.
        let (w, h) = (640, 640);
        let ring: Vec<(usize, usize)> = (0..w * h)
            .map(|i| (i % w, i / w))
            .filter(|&(u, v)| (40..600).contains(&u) && (40..600).contains(&v))
            .filter(|&(u, v)| !((44..596).contains(&u) && (44..596).contains(&v)))
            .collect();
        let marked = marks(w, h, &ring);
        let shape = TileShape::new(16, 32).unwrap();
        let tiles = plan_tiles(w, h, &marked, shape);
        let pixels: usize = tiles.iter().map(|t| t.input.area()).sum();
        // The bounding box is the whole frame; four thin sides would read 44% of it.
        assert!(tiles.len() >= 4 && pixels * 5 < w * h * 3, "{} tiles read {pixels} pixels", tiles.len());
        // Every marked pixel lies in exactly one core, and each core has its margin in its tile
        // wherever the frame allows.
        for &(u, v) in &ring {
            let holders: Vec<(&Tile, &Rect)> = tiles
                .iter()
                .flat_map(|t| t.cores.iter().map(move |c| (t, c)))
                .filter(|(_, c)| (c.x..c.x + c.width).contains(&u) && (c.y..c.y + c.height).contains(&v))
                .collect();
            assert_eq!(holders.len(), 1, "({u}, {v})");
            let (tile, core) = holders[0];
            let (i, c) = (tile.input, core);
            assert!(i.x <= c.x.saturating_sub(32) && i.y <= c.y.saturating_sub(32));
            assert!(i.x + i.width >= (c.x + c.width + 32).min(w) && i.y + i.height >= (c.y + c.height + 32).min(h));
        }
    }

    #[test]
    fn a_shape_shrinks_with_the_frame_to_multiples_of_the_alignment() {
        let shape = TileShape::DEFAULT;
        assert_eq!(shape.shrunk_by(1), shape);
        assert_eq!(shape.shrunk_by(0), shape, "factor 0 reads as 1");
        assert_eq!(shape.shrunk_by(2), TileShape { core: 16, margin: 16 });
        // 32 / 3 = 10.7 rounds up to one alignment step; a margin of 0 stays 0.
        assert_eq!(shape.shrunk_by(3), TileShape { core: 16, margin: 16 });
        assert_eq!(TileShape::new(64, 0).unwrap().shrunk_by(2), TileShape { core: 32, margin: 0 });
        assert_eq!(TileShape::new(96, 48).unwrap().shrunk_by(2), TileShape { core: 48, margin: 32 });
        assert_eq!(TileShape::new(16, 16).unwrap().shrunk_by(4), TileShape { core: 16, margin: 16 });
    }

    /// Cells whose needs (core plus margin) overlap or touch are planned together: next to each
    /// other across or down, at the frame's first and last rows and columns too, or three cells apart, where
    /// 32 pixels of margin on each side just meet. Four cells apart they do not, and stay apart.
    #[test]
    fn cells_whose_needs_touch_share_a_tile() {
        let (w, h) = (320, 240);
        let plan = |pixels: &[(usize, usize)]| plan_tiles(w, h, &marks(w, h, pixels), TileShape::DEFAULT);
        for pair in [
            [(5, 5), (40, 5)],
            [(5, 5), (5, 40)],
            [(5, 5), (100, 5)],
            [(5, 5), (5, 100)],
            [(300, 5), (300, 40)],
            [(300, 230), (250, 230)],
        ] {
            let tiles = plan(&pair);
            assert_eq!(tiles.len(), 1, "{pair:?}: {tiles:?}");
            assert_eq!(tiles[0].cores.len(), 2, "{pair:?}");
        }
        for pair in [[(5, 5), (140, 5)], [(5, 5), (5, 140)]] {
            assert_eq!(plan(&pair).len(), 2, "{pair:?}");
        }
        // A cell four apart is not grouped with the pair: one group of all three would be cut at its
        // median, between the two neighbours, and read their shared margin twice.
        let tiles = plan(&[(5, 5), (40, 5), (165, 5)]);
        assert_eq!(tiles.iter().map(|t| t.cores.len()).collect::<Vec<_>>(), [2, 1], "{tiles:?}");
    }
}
