//! The filling rules every method shares: the common new-region rule (ALGORITHMS.md §4.1), the `fill`
//! rule (the background neighbour of a disocclusion), the thin-run rule of the iterative infilling
//! (ALGORITHMS.md §6.5), the distance into a hole that the far blur grows with, and copies along
//! integer vectors.

use rayon::prelude::*;

use crate::geometry::image::is_valid_depth;
use crate::geometry::nearest::NearestKnown;
use crate::geometry::{DepthMap, Direction, HoleMask, Pixel, PixelClass, RgbImage, VectorField};

/// City-block distance (the pixels compared here always share a row or a column).
#[inline]
fn distance(a: Pixel, b: Pixel) -> usize {
    a.0.abs_diff(b.0) + a.1.abs_diff(b.1)
}

/// Of two pixels on either side of `p`, the closer one; the first on a tie or when only it exists.
fn closer(p: Pixel, first: Option<Pixel>, second: Option<Pixel>) -> Option<Pixel> {
    match (first, second) {
        (Some(a), Some(b)) => Some(if distance(b, p) < distance(a, p) { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// The pixel a new-region pixel copies: the nearest known pixel along its row (tie: left), else
/// along its column (tie: up).
pub fn new_region_source(nearest: &NearestKnown, p: Pixel) -> Option<Pixel> {
    let along_row = closer(p, nearest.beyond(p, Direction::Left), nearest.beyond(p, Direction::Right));
    along_row.or_else(|| closer(p, nearest.beyond(p, Direction::Up), nearest.beyond(p, Direction::Down)))
}

/// The pixel the `fill` rule copies into hole pixel `p`: of the nearest known pixels in the four
/// directions, the one with the largest warped depth (the background); ties go to the first of
/// left, right, up, down. A known pixel without a valid depth loses to any with one.
pub fn background_source(nearest: &NearestKnown, warped_depth: &DepthMap, p: Pixel) -> Option<Pixel> {
    farthest(warped_depth, nearest.around(p).into_iter().flatten())
}

/// The distance from `p` to the nearest known pixel along its row or column (infinite if there is
/// none): how far into a hole `p` lies, for the far blur.
pub fn distance_to_known(nearest: &NearestKnown, p: Pixel) -> f32 {
    nearest.around(p).into_iter().flatten().map(|q| distance(q, p) as f32).fold(f32::INFINITY, f32::min)
}

/// The default longest thin run (`--thin-run`): unknown runs of at most this many pixels between
/// two known pixels of a row or a column are filled by [`thin_run_source`], not the network. On
/// the 12 Blender clips at 320x240 the recipe's five seeds score 486.7-520.7 D-MSE with the
/// network on them and 453.1-455.2 with the rule (results/recipe-hd/README.md, "Thin runs").
pub const THIN_RUN: usize = 3;

/// The pixel a hole pixel `p` in a thin run copies, if it is in one: when at most `max_run` (0:
/// never) unknown pixels lie between the nearest known pixels left and right of `p`, the one of
/// the two with the larger warped depth (tie: left); else the same along its column (tie: up). A
/// sliver that narrow is uncovered beside the edge of the object that hid it, and the background
/// next to it continues into it; the network, which sees the frame through 2x2 poolings, tends to
/// read a few pixels past that neighbour, where the background has changed already.
pub fn thin_run_source(nearest: &NearestKnown, warped_depth: &DepthMap, p: Pixel, max_run: usize) -> Option<Pixel> {
    let across = |before: Direction, after: Direction, position: fn(Pixel) -> usize| {
        let (a, b) = (nearest.beyond(p, before)?, nearest.beyond(p, after)?);
        (position(b) - position(a) - 1 <= max_run).then(|| farthest(warped_depth, [a, b]))?
    };
    across(Direction::Left, Direction::Right, |q| q.0).or_else(|| across(Direction::Up, Direction::Down, |q| q.1))
}

/// Of `candidates`, the one with the largest warped depth, the first on a tie; one without a valid
/// depth loses to any with one.
fn farthest(warped_depth: &DepthMap, candidates: impl IntoIterator<Item = Pixel>) -> Option<Pixel> {
    let depth_key = |(u, v): Pixel| {
        let z = warped_depth.at(u, v);
        if is_valid_depth(z) {
            z
        } else {
            f32::NEG_INFINITY
        }
    };
    let mut best: Option<(Pixel, f32)> = None;
    for q in candidates {
        let z = depth_key(q);
        if best.is_none_or(|(_, best_z)| z > best_z) {
            best = Some((q, z));
        }
    }
    best.map(|(q, _)| q)
}

/// Copies into every pixel of class `class` the pixel `source` names for it (if any).
///
/// Sources must be known pixels: they are never written here, so the copies can be planned in
/// parallel and applied in any order with the same result.
fn copy_from_sources(
    image: &mut RgbImage,
    holes: &HoleMask,
    class: PixelClass,
    source: impl Fn(Pixel) -> Option<Pixel> + Sync,
) {
    let w = image.width();
    let copies: Vec<(usize, usize)> = (0..image.height())
        .into_par_iter()
        .flat_map_iter(|v| {
            let source = &source;
            (0..w).filter(move |&u| holes.class(u, v) == class).filter_map(move |u| {
                let (su, sv) = source((u, v))?;
                debug_assert!(holes.is_known(su, sv), "source ({su}, {sv}) is a hole");
                Some((v * w + u, sv * w + su))
            })
        })
        .collect();
    let pixels = image.pixels_mut();
    for (dst, src) in copies {
        pixels[dst] = pixels[src];
    }
}

fn assert_mask_matches(image: &RgbImage, holes: &HoleMask) {
    assert!(
        image.width() == holes.width() && image.height() == holes.height(),
        "image {}x{} and hole mask {}x{} differ in size",
        image.width(),
        image.height(),
        holes.width(),
        holes.height()
    );
}

// ---------------------------------------------------------------------------------------------
// Filling rules
// ---------------------------------------------------------------------------------------------

/// The common new-region rule of ALGORITHMS.md §4.1: every new-region pixel copies the nearest known pixel
/// along its row (tie: left), else along its column (tie: up), else stays as it is. Reads known
/// pixels only, so it can run before or after the disocclusions are infilled.
pub fn fill_new_regions(image: &mut RgbImage, holes: &HoleMask) {
    let nearest = NearestKnown::new(holes.width(), holes.height(), &holes.known());
    fill_new_regions_with(image, holes, &nearest);
}

/// [`fill_new_regions`] with the [`NearestKnown`] of `holes`' known mask already built.
pub fn fill_new_regions_with(image: &mut RgbImage, holes: &HoleMask, nearest: &NearestKnown) {
    assert_mask_matches(image, holes);
    assert!(nearest.width() == holes.width() && nearest.height() == holes.height(), "nearest-known size differs");
    copy_from_sources(image, holes, PixelClass::NewRegion, |p| new_region_source(nearest, p));
}

/// The `fill` rule: every disocclusion pixel copies, of the nearest known pixels in the four
/// directions, the one with the largest warped depth (a disocclusion is background uncovered
/// behind a foreground object, so the farther side is the likelier match).
pub fn fill_disocclusions_background(image: &mut RgbImage, warped_depth: &DepthMap, holes: &HoleMask) {
    assert_mask_matches(image, holes);
    assert!(image.same_size(warped_depth), "image and warped depth differ in size");
    let nearest = NearestKnown::new(holes.width(), holes.height(), &holes.known());
    copy_from_sources(image, holes, PixelClass::Disocclusion, |p| background_source(&nearest, warped_depth, p));
}

/// Copies `source` at `p + vector` into every pixel `p` whose (integer) vector is not zero.
/// The targets must be known pixels of `source` inside the frame (fictitious vectors are).
pub(crate) fn copy_along_vectors(image: &mut RgbImage, source: &RgbImage, vectors: &VectorField) {
    let w = image.width();
    image.pixels_mut().par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
        for (u, out) in row.iter_mut().enumerate() {
            let [a, b] = vectors.get(u, v);
            if a != 0.0 || b != 0.0 {
                let su = (u as f32 + a).round() as usize;
                let sv = (v as f32 + b).round() as usize;
                *out = source.get(su, sv);
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Image;
    use crate::test_scene::{classes_from_rows, labelled, BLUE, GREEN, RED};

    #[test]
    fn new_regions_copy_the_nearest_known_pixel_in_the_row_then_the_column() {
        let holes = classes_from_rows(&[
            "KNNKNNK", // (1,0): left at 1 beats right at 2; (2,0): right at 1; (4,0)/(5,0) likewise
            "KNKNNNN", // (1,1): tie between 0 and 2 -> left; (3..6,1): only the left one at 2
            "NNNNNNN", // nothing in the row: (0,2) column: up (0,1) at 1, down (0,4) at 2 -> up
            "NNNNNNN", // (0,3): up at 2, down at 1 -> down; (2,3): up (2,1) at 2, down (2,4) at 1 -> down
            "KNKNNNN", // column 4 has no known pixel: (4,2), (4,3) unchanged; (6,3): only up (6,0)
        ]);
        let original = labelled(7, 5);
        let mut image = original.clone();
        fill_new_regions(&mut image, &holes);
        let o = |u, v| original.get(u, v);
        let expected = [
            ((1, 0), o(0, 0)),
            ((2, 0), o(3, 0)),
            ((4, 0), o(3, 0)),
            ((5, 0), o(6, 0)),
            ((1, 1), o(0, 1)),
            ((5, 1), o(2, 1)),
            ((0, 2), o(0, 1)),
            ((2, 2), o(2, 1)),
            ((0, 3), o(0, 4)),
            ((2, 3), o(2, 4)),
            ((3, 2), o(3, 0)),
            ((4, 2), o(4, 2)),
            ((4, 3), o(4, 3)),
            ((6, 3), o(6, 0)),
        ];
        for ((u, v), want) in expected {
            assert_eq!(image.get(u, v), want, "({u}, {v})");
        }
        // Known pixels are never touched.
        for (i, class) in holes.classes().iter().enumerate() {
            if *class == PixelClass::Known {
                assert_eq!(image.pixels()[i], original.pixels()[i]);
            }
        }
    }

    #[test]
    fn new_region_rule_leaves_disocclusions_alone() {
        let holes = classes_from_rows(&["KKK", "KDK", "KKK"]);
        let mut image = Image::filled(3, 3, RED);
        image.set(1, 1, BLUE);
        fill_new_regions(&mut image, &holes);
        assert_eq!(image.get(1, 1), BLUE);
    }

    #[test]
    fn fill_copies_the_farthest_of_the_four_nearest_known_pixels() {
        let holes = classes_from_rows(&["KKKKK", "KKKKK", "KKDDK", "KKKKK", "KKKKK"]);
        // (2,2): left (1,2) near/red, right (4,2) far/blue, up and down middle/green.
        let mut depth = Image::filled(5, 5, [5.0]);
        depth.set(1, 2, [1.0]);
        depth.set(4, 2, [10.0]);
        let mut image = Image::filled(5, 5, GREEN);
        image.set(1, 2, RED);
        image.set(4, 2, BLUE);
        for (u, v) in [(2, 2), (3, 2)] {
            image.set(u, v, [0.0; 3]);
            depth.set(u, v, [0.0]);
        }
        let mut filled = image.clone();
        fill_disocclusions_background(&mut filled, &depth, &holes);
        assert_eq!(filled.get(2, 2), BLUE);
        assert_eq!(filled.get(3, 2), BLUE);

        // Ties: left and right equally far -> left; up and down only -> up.
        depth.set(1, 2, [10.0]);
        depth.set(2, 1, [10.0]);
        depth.set(2, 3, [10.0]);
        image.set(2, 1, [0.3; 3]);
        image.set(2, 3, [0.7; 3]);
        let mut filled = image.clone();
        fill_disocclusions_background(&mut filled, &depth, &holes);
        assert_eq!(filled.get(2, 2), RED);
        depth.set(1, 2, [1.0]);
        depth.set(4, 2, [1.0]);
        let mut filled = image.clone();
        fill_disocclusions_background(&mut filled, &depth, &holes);
        assert_eq!(filled.get(2, 2), [0.3; 3]);
    }

    #[test]
    fn fill_prefers_a_valid_depth_over_an_invalid_one() {
        let holes = classes_from_rows(&["KKK", "KDK", "KKK"]);
        let depth = Image::from_fn(3, 3, |u, _| [if u == 0 { f32::NAN } else { 0.5 }]);
        let mut image = labelled(3, 3);
        fill_disocclusions_background(&mut image, &depth, &holes);
        // Left has NaN depth, right (2,1) valid: right wins.
        assert_eq!(image.get(1, 1), labelled(3, 3).get(2, 1));
    }

    #[test]
    fn thin_runs_copy_the_farther_end_of_their_row_else_of_their_column() {
        let holes = classes_from_rows(&[
            "KKKKKKKKK",
            "KDDDKDDDD", // run of 3 between (0,1) and (4,1); (5..8,1) reach the border
            "KDDDDKKKK", // run of 4: thin along no row; (1,2)..(3,2) are thin along their columns
            "KKKKKKKKK",
        ]);
        let nearest = NearestKnown::new(9, 4, &holes.known());
        // Depth grows to the right and down, except that (0, 1) is far.
        let mut depth = Image::from_fn(9, 4, |u, v| [1.0 + u as f32 + 10.0 * v as f32]);
        depth.set(0, 1, [100.0]);
        let source = |p, max_run| thin_run_source(&nearest, &depth, p, max_run);
        for u in 1..=3 {
            assert_eq!(source((u, 1), 3), Some((0, 1)), "({u}, 1): the farther end of its row");
            assert_eq!(source((u, 1), 2), Some((u, 3)), "({u}, 1): too long a row; its column's farther end");
            assert_eq!(source((u, 1), 0), None, "0 turns the rule off");
        }
        // No known pixel right of (5..8, 1): thin along the column only (between rows 0 and 2, or 0 and 3).
        assert_eq!(source((6, 1), 3), Some((6, 2)));
        assert_eq!(source((4, 2), 1), Some((4, 3)), "a run of 4 along the row, of 1 along the column");
        assert_eq!(source((1, 2), 2), Some((1, 3)), "a run of 4 along the row, of 2 along the column");
        assert_eq!(source((1, 2), 1), None);
    }

    #[test]
    fn thin_runs_break_ties_towards_the_first_end_and_prefer_a_valid_depth() {
        let holes = classes_from_rows(&["KKKK", "KDDK", "KKKK"]);
        let nearest = NearestKnown::new(4, 3, &holes.known());
        let mut depth = Image::filled(4, 3, [2.0]);
        assert_eq!(thin_run_source(&nearest, &depth, (2, 1), 3), Some((0, 1)), "a tie goes left");
        for bad in [f32::NAN, f32::INFINITY, 0.0, -1.0] {
            depth.set(0, 1, [bad]);
            assert_eq!(thin_run_source(&nearest, &depth, (1, 1), 3), Some((3, 1)), "left depth {bad}");
        }
        // Neither end has a valid depth: the first still gives a colour.
        depth.set(3, 1, [f32::NAN]);
        assert_eq!(thin_run_source(&nearest, &depth, (1, 1), 3), Some((0, 1)));
    }

    #[test]
    fn copies_along_vectors_read_both_components_and_skip_zero_vectors() {
        let source = labelled(5, 4);
        let mut image = RgbImage::zeros(5, 4);
        let mut vectors = VectorField::zeros(5, 4);
        vectors.set(0, 0, [1.0, 2.0]);
        vectors.set(3, 3, [-2.0, -3.0]);
        vectors.set(4, 1, [0.0, 0.6]); // rounds to the pixel below
        copy_along_vectors(&mut image, &source, &vectors);
        assert_eq!(image.get(0, 0), source.get(1, 2));
        assert_eq!(image.get(3, 3), source.get(1, 0));
        assert_eq!(image.get(4, 1), source.get(4, 2));
        assert_eq!(image.get(2, 1), [0.0; 3], "a zero vector copies nothing");
    }

    #[test]
    #[should_panic(expected = "differ in size")]
    fn new_regions_refuse_a_mask_of_another_size() {
        fill_new_regions(&mut RgbImage::zeros(4, 2), &classes_from_rows(&["KNK", "KKN"]));
    }

    #[test]
    #[should_panic(expected = "differ in size")]
    fn fill_refuses_a_mask_of_another_size() {
        let holes = classes_from_rows(&["KDK", "KKD"]);
        fill_disocclusions_background(&mut RgbImage::zeros(4, 2), &Image::filled(4, 2, [1.0]), &holes);
    }
}
