//! The far blur (ALGORITHMS.md §6.5, "The far blur"): after the passes, each infilled
//! disocclusion pixel takes the mean of the infilled colours around it, over a neighbourhood that
//! grows with its distance to the nearest known pixel.
//!
//! A colour copied into a pixel next to the known frame continues the background that borders
//! it; deep inside a wide hole, a copy from its edge is one plausible texture among many, and
//! against the truth it errs twice as much as the texture's mean would. Averaging the infilled
//! colours over a Gaussian-like window of width `strength x distance` trades that detail for the
//! local mean where the copy knows least. On the Blender clips it takes the recipe's five seeds
//! from 0.67-0.69x to 0.55-0.58x `fill` in D-MSE at 1080p (where holes are 30-50 pixels wide) and
//! from 0.51x to 0.50x at 320x240, D-SSIM a little higher at both (results/recipe-hd/README.md,
//! "The far blur").
//!
//! The window is read from a pyramid of the infilled pixels alone (known and new-region pixels
//! weigh 0): level 0 is the frame, level `j` averages 2x2 cells of level `j - 1` (the last row or
//! column repeated at odd sizes); each level is smoothed by the binomial kernel
//! `[1 4 6 4 1] / 16` along both axes (edges repeated), read bilinearly at the pixel's position
//! (clamped to the level) and divided by the weight read there. A pixel whose window `s =
//! strength x distance` is below 1 mixes its own colour with level 0 by `s`; above, it
//! interpolates between levels `floor(log2 s)` and the next on `log2 s`, up to [`LEVELS`] `- 1`.

use rayon::prelude::*;

use crate::geometry::RgbImage;

/// The default strength (`--far-blur`): the window's width per pixel of distance; 0 turns the
/// blur off. From 0.35 to 1.0 the Blender clips at 1080p score within 1.6% (two seeds); at
/// 320x240 0.7 gains 0.8% more than 0.5, which was chosen before that was measured.
pub const FAR_BLUR: f32 = 0.5;

/// Pyramid levels: the widest window averages cells of 32x32 pixels.
pub const LEVELS: usize = 6;

/// The binomial kernel of each level's smoothing.
const KERNEL: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];

/// Blurs the pixels `pixels` (row-major indices into `image`, each once) from one another, pixel
/// `pixels[k]` over a window of `strength * distances[k]` pixels (see the module's notes);
/// every other pixel is left as it is and read by none. A non-finite distance takes the widest
/// window; `strength <= 0` or no pixels leave the image as it is.
///
/// Panics if `distances` and `pixels` differ in length or a pixel lies outside the image.
pub fn blur_far_pixels(image: &mut RgbImage, pixels: &[usize], distances: &[f32], strength: f32) {
    assert_eq!(pixels.len(), distances.len(), "one distance per pixel");
    if pixels.is_empty() || strength.is_nan() || strength <= 0.0 {
        return;
    }
    let (w, h) = (image.width(), image.height());
    assert!(pixels.iter().all(|&i| i < w * h), "a pixel to blur lies outside the {w}x{h} image");
    let windows: Vec<f32> = distances.iter().map(|&d| if d.is_nan() { f32::INFINITY } else { strength * d }).collect();

    // Level 0 is read at the pixels themselves; the levels above it keep only the tiles near
    // the pixels (every cell elsewhere is 0), so that a frame with a few holes costs little.
    let mut member = vec![false; w * h];
    pixels.iter().for_each(|&i| member[i] = true);
    let deepest = windows.iter().fold(0.0f32, |a, &s| a.max(s));
    let levels_needed = if deepest < 1.0 { 1 } else { (top_level(deepest) as usize + 2).min(LEVELS) };
    let mut smoothed: Vec<Grid> = Vec::with_capacity(levels_needed);
    if levels_needed > 1 {
        // The cells that hold pixels, level by level: each listed once per run along a row.
        let positions: Vec<(usize, usize)> = pixels.iter().map(|&i| (i % w, i / w)).collect();
        let mut cells = halved(&positions);
        let mut level = Grid::first_pooled(image, pixels, &positions, &cells);
        smoothed.push(level.smoothed());
        for _ in 2..levels_needed {
            cells = halved(&cells);
            level = level.pooled(&cells);
            smoothed.push(level.smoothed());
        }
    }
    let level_zero = |u: usize, v: usize| {
        let mut sum = [0.0f32; 4];
        for (dy, ky) in KERNEL.iter().enumerate() {
            let y = (v + dy).saturating_sub(2).min(h - 1);
            for (dx, kx) in KERNEL.iter().enumerate() {
                let i = y * w + (u + dx).saturating_sub(2).min(w - 1);
                if member[i] {
                    let [r, g, b] = image.pixels()[i];
                    let k = kx * ky;
                    sum = [sum[0] + k * r, sum[1] + k * g, sum[2] + k * b, sum[3] + k];
                }
            }
        }
        mean(sum)
    };

    let blurred: Vec<[f32; 3]> = pixels
        .par_iter()
        .zip(&windows)
        .map(|(&i, &window)| {
            let (u, v) = (i % w, i / w);
            let own = image.pixels()[i];
            let at_level =
                |j: usize| if j == 0 { level_zero(u, v) } else { smoothed[j - 1].mean_at(u, v, j) }.unwrap_or(own);
            if window <= 0.0 {
                own
            } else if window < 1.0 {
                mix(own, at_level(0), window)
            } else {
                let l = top_level(window);
                let lo = (l.floor() as usize).min(levels_needed - 1);
                let hi = (lo + 1).min(levels_needed - 1);
                mix(at_level(lo), at_level(hi), l - lo as f32)
            }
        })
        .collect();
    for (&i, colour) in pixels.iter().zip(blurred) {
        image.pixels_mut()[i] = colour;
    }
}

/// Cells beyond a pixel's own cell that a level's smoothing (2) and bilinear read (1) may touch.
const MARGIN: usize = 3;

/// Side of the square tiles a level keeps, in cells (a power of two larger than [`MARGIN`]).
const TILE: usize = 16;

/// The cells of the next level that hold the cells `cells`, in their order, without repeating
/// the last one listed.
fn halved(cells: &[(usize, usize)]) -> Vec<(usize, usize)> {
    let mut next: Vec<(usize, usize)> = cells.iter().map(|&(x, y)| (x / 2, y / 2)).collect();
    next.dedup();
    next
}

/// The pyramid level, fractional, of a window of `window >= 1` pixels.
fn top_level(window: f32) -> f32 {
    window.log2().min((LEVELS - 1) as f32)
}

/// A weighted sum of colours over its weight, if any weighs.
fn mean([r, g, b, weight]: [f32; 4]) -> Option<[f32; 3]> {
    (weight > 1e-9).then(|| [r / weight, g / weight, b / weight])
}

fn mix(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    std::array::from_fn(|c| (1.0 - t) * a[c] + t * b[c])
}

/// One level of the pyramid, `width x height` cells of (colour x weight, weight), kept in the
/// tiles of [`TILE`] x [`TILE`] cells within [`MARGIN`] cells of a pixel's own cell: every cell
/// elsewhere is 0.
struct Grid {
    width: usize,
    height: usize,
    tiles_x: usize,
    /// Per tile, row-major, its place in `cells` (in tiles), or `ABSENT`.
    tile_index: Vec<u32>,
    /// The cells of each tile kept, row-major within the tile.
    cells: Vec<[f32; 4]>,
    /// Per tile kept, its position (in tiles).
    tiles: Vec<(usize, usize)>,
}

const ABSENT: u32 = u32::MAX;

impl Grid {
    /// An empty level of `width x height` cells with the tiles near the cells `cells` (those
    /// that hold pixels) kept.
    fn near_pixels(width: usize, height: usize, cells: &[(usize, usize)]) -> Grid {
        let (tiles_x, tiles_y) = (width.div_ceil(TILE), height.div_ceil(TILE));
        let mut tile_index = vec![ABSENT; tiles_x * tiles_y];
        let mut tiles = Vec::new();
        for &(x, y) in cells {
            let (x0, x1) = (x.saturating_sub(MARGIN) / TILE, (x + MARGIN).min(width - 1) / TILE);
            let (y0, y1) = (y.saturating_sub(MARGIN) / TILE, (y + MARGIN).min(height - 1) / TILE);
            for ty in y0..=y1 {
                for tx in x0..=x1 {
                    let slot = &mut tile_index[ty * tiles_x + tx];
                    if *slot == ABSENT {
                        *slot = tiles.len() as u32;
                        tiles.push((tx, ty));
                    }
                }
            }
        }
        let cells = vec![[0.0; 4]; tiles.len() * TILE * TILE];
        Grid { width, height, tiles_x, tile_index, cells, tiles }
    }

    /// The same tiles, all cells 0.
    fn zeros_like(&self) -> Grid {
        Grid {
            width: self.width,
            height: self.height,
            tiles_x: self.tiles_x,
            tile_index: self.tile_index.clone(),
            cells: vec![[0.0; 4]; self.cells.len()],
            tiles: self.tiles.clone(),
        }
    }

    /// Where cell `(x, y)` is kept, if it is.
    fn slot(&self, x: usize, y: usize) -> Option<usize> {
        let tile = self.tile_index[(y / TILE) * self.tiles_x + x / TILE];
        (tile != ABSENT).then(|| tile as usize * TILE * TILE + (y % TILE) * TILE + x % TILE)
    }

    /// The cell at `(x, y)`, with positions outside the level clamped to its edge.
    fn get(&self, x: isize, y: isize) -> [f32; 4] {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.slot(x, y).map_or([0.0; 4], |k| self.cells[k])
    }

    /// Every kept cell computed from its position, in parallel over tiles.
    fn fill_cells(&mut self, cell: impl Fn(isize, isize) -> [f32; 4] + Sync) {
        let tiles = &self.tiles;
        self.cells.par_chunks_mut(TILE * TILE).zip(tiles).for_each(|(cells, &(tx, ty))| {
            for (k, value) in cells.iter_mut().enumerate() {
                *value = cell((tx * TILE + k % TILE) as isize, (ty * TILE + k / TILE) as isize);
            }
        });
    }

    /// Level 1 of the pixels `pixels` of `image` (weight 1 each, every other pixel 0), at
    /// `positions` and in the level's `cells`: each pixel adds a quarter of itself to its cell,
    /// twice that in the last row or column of an odd side (which its cell reads twice).
    fn first_pooled(
        image: &RgbImage,
        pixels: &[usize],
        positions: &[(usize, usize)],
        cells: &[(usize, usize)],
    ) -> Grid {
        let (w, h) = (image.width(), image.height());
        let mut level = Grid::near_pixels(w.div_ceil(2), h.div_ceil(2), cells);
        let repeats = |x: usize, n: usize| if n % 2 == 1 && x == n - 1 { 2.0 } else { 1.0 };
        for (&i, &(u, v)) in pixels.iter().zip(positions) {
            let weight = 0.25 * repeats(u, w) * repeats(v, h);
            let [r, g, b] = image.pixels()[i];
            let k = level.slot(u / 2, v / 2).expect("a pixel's own cell is kept");
            let cell = &mut level.cells[k];
            *cell = [cell[0] + weight * r, cell[1] + weight * g, cell[2] + weight * b, cell[3] + weight];
        }
        level
    }

    /// The next level of this one, whose `cells` hold pixels: 2x2 cells averaged.
    fn pooled(&self, cells: &[(usize, usize)]) -> Grid {
        let mut next = Grid::near_pixels(self.width.div_ceil(2), self.height.div_ceil(2), cells);
        next.fill_cells(|x, y| {
            let children = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| self.get(2 * x + dx, 2 * y + dy));
            std::array::from_fn(|c| 0.25 * children.iter().map(|child| child[c]).sum::<f32>())
        });
        next
    }

    /// The level smoothed by [`KERNEL`] along rows, then columns.
    ///
    /// Tile by tile: the tile and the two cells around it are read once (positions clamped to
    /// the level, cells of tiles not kept 0), smoothed along the rows of that block, then along
    /// the columns. A cell outside the kept tiles is at least [`MARGIN`] cells from every
    /// infilled pixel's cell, more than the kernel's reach, so its smoothing along rows is 0, as
    /// a cell not kept reads: the same sums, added in the same order, as two passes over whole
    /// levels.
    fn smoothed(&self) -> Grid {
        const REACH: usize = KERNEL.len() / 2;
        const SIDE: usize = TILE + 2 * REACH;
        let mut out = self.zeros_like();
        let tiles = &self.tiles;
        out.cells.par_chunks_mut(TILE * TILE).zip(tiles).for_each(|(cells, &(tx, ty))| {
            let (x0, y0) = ((tx * TILE) as isize - REACH as isize, (ty * TILE) as isize - REACH as isize);
            let mut block = [[[0.0f32; 4]; SIDE]; SIDE];
            for (r, row) in block.iter_mut().enumerate() {
                for (c, cell) in row.iter_mut().enumerate() {
                    *cell = self.get(x0 + c as isize, y0 + r as isize);
                }
            }
            let mut along_rows = [[[0.0f32; 4]; TILE]; SIDE];
            for (row, source) in along_rows.iter_mut().zip(&block) {
                for (x, cell) in row.iter_mut().enumerate() {
                    for (t, weight) in KERNEL.iter().enumerate() {
                        cell.iter_mut().zip(source[x + t]).for_each(|(s, v)| *s += weight * v);
                    }
                }
            }
            for (k, cell) in cells.iter_mut().enumerate() {
                let (x, y) = (k % TILE, k / TILE);
                let mut sum = [0.0f32; 4];
                for (t, weight) in KERNEL.iter().enumerate() {
                    sum.iter_mut().zip(along_rows[y + t][x]).for_each(|(s, v)| *s += weight * v);
                }
                *cell = sum;
            }
        });
        out
    }

    /// The mean colour of level `j` at full-size pixel `(u, v)` (bilinear, position clamped to the
    /// level), or `None` where no infilled pixel weighs.
    fn mean_at(&self, u: usize, v: usize, j: usize) -> Option<[f32; 3]> {
        let scale = (1usize << j) as f32;
        let clamp = |p: f32, n: usize| p.clamp(0.0, (n - 1) as f32);
        let x = clamp((u as f32 + 0.5) / scale - 0.5, self.width);
        let y = clamp((v as f32 + 0.5) / scale - 0.5, self.height);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as isize, y0 as isize);
        let mut sum = [0.0f32; 4];
        for (dx, dy, weight) in
            [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)]
        {
            if weight > 0.0 {
                let value = self.get(x0 + dx, y0 + dy);
                sum.iter_mut().zip(value).for_each(|(s, v)| *s += weight * v);
            }
        }
        mean(sum)
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// The far blur as the module's notes state it, with every level kept whole.
    fn dense_reference(image: &RgbImage, pixels: &[usize], distances: &[f32], strength: f32) -> RgbImage {
        let (w, h) = (image.width(), image.height());
        let mut level: Vec<Vec<[f32; 4]>> = vec![vec![[0.0; 4]; w]; h];
        for &i in pixels {
            let [r, g, b] = image.pixels()[i];
            level[i / w][i % w] = [r, g, b, 1.0];
        }
        let clamp = |p: isize, n: usize| p.clamp(0, n as isize - 1) as usize;
        let smooth = |grid: &Vec<Vec<[f32; 4]>>| {
            let (gh, gw) = (grid.len(), grid[0].len());
            let pass = |grid: &Vec<Vec<[f32; 4]>>, dx: isize, dy: isize| {
                let mut out = vec![vec![[0.0f32; 4]; gw]; gh];
                for (y, row) in out.iter_mut().enumerate() {
                    for (x, cell) in row.iter_mut().enumerate() {
                        for (t, k) in KERNEL.iter().enumerate() {
                            let o = t as isize - 2;
                            let v = grid[clamp(y as isize + o * dy, gh)][clamp(x as isize + o * dx, gw)];
                            (0..4).for_each(|c| cell[c] += k * v[c]);
                        }
                    }
                }
                out
            };
            pass(&pass(grid, 1, 0), 0, 1)
        };
        let mut smoothed = vec![smooth(&level)];
        for _ in 1..LEVELS {
            let (gh, gw) = (level.len(), level[0].len());
            level = (0..gh.div_ceil(2))
                .map(|y| {
                    (0..gw.div_ceil(2))
                        .map(|x| {
                            let at = |dx: usize, dy: usize| level[(2 * y + dy).min(gh - 1)][(2 * x + dx).min(gw - 1)];
                            let cells = [at(0, 0), at(1, 0), at(0, 1), at(1, 1)];
                            std::array::from_fn(|c| 0.25 * cells.iter().map(|cell| cell[c]).sum::<f32>())
                        })
                        .collect()
                })
                .collect();
            smoothed.push(smooth(&level));
        }
        let mut out = image.clone();
        for (&i, &d) in pixels.iter().zip(distances) {
            let (u, v) = (i % w, i / w);
            let own = image.pixels()[i];
            let read = |j: usize| {
                let grid = &smoothed[j];
                let (gh, gw) = (grid.len(), grid[0].len());
                let s = (1 << j) as f32;
                let x = ((u as f32 + 0.5) / s - 0.5).clamp(0.0, (gw - 1) as f32);
                let y = ((v as f32 + 0.5) / s - 0.5).clamp(0.0, (gh - 1) as f32);
                let (x0, y0) = (x.floor() as usize, y.floor() as usize);
                let (fx, fy) = (x - x0 as f32, y - y0 as f32);
                let (x1, y1) = ((x0 + 1).min(gw - 1), (y0 + 1).min(gh - 1));
                let c: [f32; 4] = std::array::from_fn(|c| {
                    (1.0 - fx) * (1.0 - fy) * grid[y0][x0][c]
                        + fx * (1.0 - fy) * grid[y0][x1][c]
                        + (1.0 - fx) * fy * grid[y1][x0][c]
                        + fx * fy * grid[y1][x1][c]
                });
                if c[3] > 1e-9 {
                    [c[0] / c[3], c[1] / c[3], c[2] / c[3]]
                } else {
                    own
                }
            };
            let window = if d.is_nan() { f32::INFINITY } else { strength * d };
            out.pixels_mut()[i] = if window < 1.0 {
                mix(own, read(0), window.max(0.0))
            } else {
                let l = window.log2().min((LEVELS - 1) as f32);
                let lo = l.floor() as usize;
                mix(read(lo), read((lo + 1).min(LEVELS - 1)), l - lo as f32)
            };
        }
        out
    }

    fn random_image(w: usize, h: usize, rng: &mut ChaCha8Rng) -> RgbImage {
        let pixels = (0..w * h).map(|_| std::array::from_fn(|_| rng.random_range(0.0..1.0))).collect();
        RgbImage::from_pixels(w, h, pixels)
    }

    fn assert_close(a: &RgbImage, b: &RgbImage, what: &str) {
        for (i, (p, q)) in a.pixels().iter().zip(b.pixels()).enumerate() {
            for c in 0..3 {
                assert!((p[c] - q[c]).abs() < 1e-5, "{what}: pixel {i} channel {c}: {} against {}", p[c], q[c]);
            }
        }
    }

    #[test]
    fn the_tiled_pyramid_matches_whole_levels_on_odd_sizes() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        // Sizes below a tile, not a multiple of it, odd at several levels, and several tiles wide.
        for (w, h) in [(9, 5), (45, 37), (150, 97), (257, 66)] {
            let image = random_image(w, h, &mut rng);
            // A wide block, scattered pixels and one pixel in a corner.
            let mut pixels: Vec<usize> = (0..w * h)
                .filter(|&i| {
                    let (u, v) = (i % w, i / w);
                    (u > w / 3 && u < w / 2 && v > 1) || rng.random_bool(0.05) || i == w * h - 1
                })
                .collect();
            pixels.dedup();
            let distances: Vec<f32> = pixels
                .iter()
                .enumerate()
                .map(|(k, _)| match k % 7 {
                    0 => 0.0,
                    1 => f32::INFINITY,
                    2 => f32::NAN,
                    3 => 0.7,
                    _ => rng.random_range(1.0..120.0),
                })
                .collect();
            let mut fast = image.clone();
            blur_far_pixels(&mut fast, &pixels, &distances, 0.5);
            assert_close(&fast, &dense_reference(&image, &pixels, &distances, 0.5), &format!("{w}x{h}"));
        }
    }

    #[test]
    fn only_the_pixels_blurred_are_read_and_written() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (w, h) = (40, 30);
        let image = random_image(w, h, &mut rng);
        let pixels: Vec<usize> =
            (0..w * h).filter(|i| (10..25).contains(&(i % w)) && (5..20).contains(&(i / w))).collect();
        let distances = vec![30.0; pixels.len()];
        let mut blurred = image.clone();
        blur_far_pixels(&mut blurred, &pixels, &distances, 1.0);
        let mut other = RgbImage::filled(w, h, [9.0, -9.0, 0.5]);
        pixels.iter().for_each(|&i| other.pixels_mut()[i] = image.pixels()[i]);
        blur_far_pixels(&mut other, &pixels, &distances, 1.0);
        for i in 0..w * h {
            if pixels.contains(&i) {
                assert_eq!(other.pixels()[i], blurred.pixels()[i], "pixel {i} read a pixel outside the set");
                assert_ne!(blurred.pixels()[i], image.pixels()[i], "pixel {i} was not blurred");
            } else {
                assert_eq!(blurred.pixels()[i], image.pixels()[i], "pixel {i} outside the set was written");
            }
        }
    }

    #[test]
    fn a_constant_hole_stays_constant_and_a_far_striped_one_fades_to_its_mean() {
        let (w, h) = (64, 64);
        let pixels: Vec<usize> = (0..w * h).collect();
        for distance in [0.5, 3.0, 40.0, f32::INFINITY] {
            let mut image = RgbImage::filled(w, h, [0.25, 0.5, 1e6]);
            blur_far_pixels(&mut image, &pixels, &vec![distance; pixels.len()], 0.5);
            for p in image.pixels() {
                assert!((p[0] - 0.25).abs() < 1e-6 && (p[1] - 0.5).abs() < 1e-6 && (p[2] - 1e6).abs() < 1.0, "{p:?}");
            }
        }
        // Rows of 0 and 1, as a copy along rows from a striped edge leaves them: near the edge the
        // stripes stay, far from it they fade towards 0.5.
        let stripes = RgbImage::from_fn(w, h, |_, v| [(v % 2) as f32; 3]);
        let contrast = |distance: f32| {
            let mut image = stripes.clone();
            blur_far_pixels(&mut image, &pixels, &vec![distance; pixels.len()], 0.5);
            let (a, b) = (image.get(32, 32)[0], image.get(32, 33)[0]);
            (a - b).abs()
        };
        assert_eq!(contrast(0.0), 1.0);
        // A window of half a pixel mixes half of level 0, where the binomial averages the stripes.
        assert!((contrast(1.0) - 0.5).abs() < 1e-6, "{}", contrast(1.0));
        assert!(contrast(16.0) < 0.1, "{}", contrast(16.0));
    }

    #[test]
    fn no_strength_and_no_pixels_change_nothing() {
        let image = random_image(12, 9, &mut ChaCha8Rng::seed_from_u64(1));
        let pixels: Vec<usize> = (20..60).collect();
        for strength in [0.0, -1.0, f32::NAN] {
            let mut out = image.clone();
            blur_far_pixels(&mut out, &pixels, &vec![10.0; pixels.len()], strength);
            assert_eq!(out.pixels(), image.pixels(), "strength {strength}");
        }
        let mut out = image.clone();
        blur_far_pixels(&mut out, &[], &[], 0.5);
        assert_eq!(out.pixels(), image.pixels());
    }

    #[test]
    #[should_panic(expected = "one distance per pixel")]
    fn distances_must_match_the_pixels() {
        blur_far_pixels(&mut RgbImage::zeros(4, 4), &[1, 2], &[1.0], 0.5);
    }
}
