//! Which parts of a frame a report magnifies: the disocclusion regions where even the best method
//! leaves the most error.
//!
//! A region is a connected component of disocclusion pixels (4-neighbours). Regions are ranked by
//! the squared error that the best method there (the one with the least error over the region,
//! among the methods that do not read the ground truth) leaves, summed over the region's pixels:
//! the regions that weigh most in the frame's D-MSE whatever the method. Each chosen region is
//! shown through a square window centred on where that error lies (its error-weighted centroid),
//! kept inside the frame; a region whose window would overlap a window already chosen by more
//! than a quarter of its area is skipped, so that two crops do not show the same place.

use ivp_core::geometry::Rect;

/// How a chosen region is described in the report.
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    /// The window shown, inside the frame.
    pub window: Rect,
    /// Disocclusion pixels of the region (the connected component, also outside the window).
    pub pixels: usize,
    /// The method with the least error over the region, by index among the methods given.
    pub best_method: usize,
    /// That method's mean squared error over the region (0..255 scale, like D-MSE).
    pub best_mse: f64,
}

/// A method's per-pixel squared error (mean over the channels, 0..255 scale), or `None` for a
/// method that may not take part in the choice (it reads the ground truth).
pub type PixelErrors<'a> = Option<&'a [f32]>;

/// The connected components of the `true` pixels of `mask` (4-neighbours), each as its pixel
/// indices in row-major order of discovery; components in order of their first pixel.
pub fn connected_components(mask: &[bool], width: usize, height: usize) -> Vec<Vec<usize>> {
    assert_eq!(mask.len(), width * height, "mask of {} entries for {width}x{height}", mask.len());
    let mut seen = vec![false; mask.len()];
    let mut components = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        let mut component = Vec::new();
        seen[start] = true;
        stack.push(start);
        while let Some(i) = stack.pop() {
            component.push(i);
            let (u, v) = (i % width, i / width);
            let neighbours = [
                (u > 0).then(|| i - 1),
                (u + 1 < width).then(|| i + 1),
                (v > 0).then(|| i - width),
                (v + 1 < height).then(|| i + width),
            ];
            for j in neighbours.into_iter().flatten() {
                if mask[j] && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        component.sort_unstable();
        components.push(component);
    }
    components
}

/// The `count` worst regions of a frame, worst first (fewer when the frame has fewer), shown
/// through windows of `window` x `window` pixels (the frame's size where it is smaller). `errors`
/// holds every method's per-pixel errors; without a method that may take part, none is chosen.
pub fn worst_regions(
    disocclusions: &[bool],
    width: usize,
    height: usize,
    errors: &[PixelErrors<'_>],
    count: usize,
    window: usize,
) -> Vec<Region> {
    let candidates: Vec<(usize, &[f32])> = errors.iter().enumerate().filter_map(|(m, e)| Some((m, (*e)?))).collect();
    if candidates.is_empty() || count == 0 {
        return Vec::new();
    }
    struct Ranked {
        total: f64,
        pixels: usize,
        best_method: usize,
        centre: (f64, f64),
    }
    let mut ranked: Vec<Ranked> = connected_components(disocclusions, width, height)
        .into_iter()
        .map(|component| {
            let total_of = |e: &[f32]| component.iter().map(|&i| f64::from(e[i])).sum::<f64>();
            let (best_method, best) = candidates
                .iter()
                .map(|&(m, e)| (m, e))
                .min_by(|a, b| total_of(a.1).total_cmp(&total_of(b.1)))
                .expect("candidates is not empty");
            let total = total_of(best);
            // Where the error lies; the component's own centre when the best method is exact.
            let weight = |i: usize| if total > 0.0 { f64::from(best[i]) } else { 1.0 };
            let weights: f64 = component.iter().map(|&i| weight(i)).sum();
            let (su, sv) = component.iter().fold((0.0, 0.0), |(su, sv), &i| {
                (su + weight(i) * (i % width) as f64, sv + weight(i) * (i / width) as f64)
            });
            Ranked { total, pixels: component.len(), best_method, centre: (su / weights, sv / weights) }
        })
        .collect();
    // Worst first; ties (exact methods) go to the larger region, then to the first found.
    ranked.sort_by(|a, b| b.total.total_cmp(&a.total).then(b.pixels.cmp(&a.pixels)));
    let (ww, wh) = (window.min(width), window.min(height));
    let mut chosen: Vec<Region> = Vec::new();
    for r in ranked {
        if chosen.len() == count {
            break;
        }
        let (cu, cv) = r.centre;
        let place = |centre: f64, size: usize, limit: usize| {
            ((centre + 0.5 - size as f64 / 2.0).round().max(0.0) as usize).min(limit - size)
        };
        let window = Rect { x: place(cu, ww, width), y: place(cv, wh, height), width: ww, height: wh };
        if chosen.iter().any(|c| 4 * overlap(&c.window, &window) > window.area()) {
            continue;
        }
        chosen.push(Region {
            window,
            pixels: r.pixels,
            best_method: r.best_method,
            best_mse: r.total / r.pixels as f64,
        });
    }
    chosen
}

/// The pixels two rectangles share.
fn overlap(a: &Rect, b: &Rect) -> usize {
    let along = |a0: usize, a1: usize, b0: usize, b1: usize| a1.min(b1).saturating_sub(a0.max(b0));
    along(a.x, a.x + a.width, b.x, b.x + b.width) * along(a.y, a.y + a.height, b.y, b.y + b.height)
}

/// Per-pixel squared error of `prediction` against `truth`, the mean over the channels on the
/// 0..255 scale: the per-pixel term of MSE (ALGORITHMS.md §7).
pub fn pixel_errors(prediction: &ivp_core::RgbImage, truth: &ivp_core::RgbImage) -> Vec<f32> {
    assert!(prediction.same_size(truth), "prediction and truth differ in size");
    prediction
        .pixels()
        .iter()
        .zip(truth.pixels())
        .map(|(p, t)| (0..3).map(|c| ((p[c] - t[c]) * 255.0).powi(2)).sum::<f32>() / 3.0)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 12x6 mask from rows of `#` (disocclusion) and `.`.
    fn mask(rows: &[&str]) -> (Vec<bool>, usize, usize) {
        let width = rows[0].len();
        (rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect(), width, rows.len())
    }

    #[test]
    fn components_join_4_neighbours_only() {
        let (m, w, h) = mask(&["##..#", "#...#", "...#.", "....."]);
        let components = connected_components(&m, w, h);
        // (3, 2) touches (4, 1) diagonally only: a component of its own.
        assert_eq!(components, vec![vec![0, 1, 5], vec![4, 9], vec![13]]);
    }

    #[test]
    fn the_worst_region_is_where_the_best_method_errs_most() {
        let (m, w, h) = mask(&[
            "##........##", //
            "##........##",
            "............",
            "............",
            "....####....",
            "....####....",
        ]);
        let n = m.len();
        // Method 0 is perfect on the left block, bad on the right one; method 1 the other way
        // round but less bad; both are bad on the bottom block, which is the largest.
        let mut a = vec![0.0f32; n];
        let mut b = vec![0.0f32; n];
        for i in 0..n {
            let (u, v) = (i % w, i / w);
            if v < 2 && u < 2 {
                b[i] = 50.0;
            } else if v < 2 && u >= 10 {
                a[i] = 100.0;
                b[i] = 40.0;
            } else if v >= 4 {
                a[i] = 30.0;
                b[i] = 20.0;
            }
        }
        // A third method reads the ground truth: it does not count.
        let errors = [Some(&a[..]), Some(&b[..]), None];
        let regions = worst_regions(&m, w, h, &errors, 5, 4);
        // Bottom: best is b at 20 x 8 = 160; right: b at 40 x 4 = 160, smaller; left: a, 0.
        assert_eq!(regions.len(), 3);
        assert_eq!((regions[0].pixels, regions[0].best_method, regions[0].best_mse), (8, 1, 20.0));
        assert_eq!(regions[0].window, Rect { x: 4, y: 2, width: 4, height: 4 });
        assert_eq!((regions[1].best_method, regions[1].best_mse), (1, 40.0));
        assert_eq!(regions[1].window, Rect { x: 8, y: 0, width: 4, height: 4 }, "kept inside the frame");
        assert_eq!((regions[2].best_method, regions[2].best_mse), (0, 0.0));
        assert_eq!(worst_regions(&m, w, h, &errors, 1, 4).len(), 1);
        assert!(worst_regions(&m, w, h, &[None], 2, 4).is_empty(), "no method may choose");
    }

    #[test]
    fn a_region_whose_window_overlaps_a_chosen_one_is_skipped_and_windows_fit_small_frames() {
        let (m, w, h) = mask(&["#.#.", "....", "...."]);
        let errors = vec![10.0f32; m.len()];
        let regions = worst_regions(&m, w, h, &[Some(&errors[..])], 2, 64);
        assert_eq!(regions.len(), 1, "both windows are the whole frame");
        assert_eq!(regions[0].window, Rect::whole(4, 3));
        // Windows of 4x4 on a 12x4 frame: the window of the hole at column 3 (columns 2..6)
        // overlaps the first one (0..4) by half (skipped), that of the hole at 10 not at all.
        let (m, w, h) = mask(&["##.#......#.", "##..........", "............", "............"]);
        let errors = vec![10.0f32; m.len()];
        let regions = worst_regions(&m, w, h, &[Some(&errors[..])], 3, 4);
        let xs: Vec<usize> = regions.iter().map(|r| r.window.x).collect();
        assert_eq!(xs, [0, 8]);
        assert_eq!(overlap(&Rect { x: 0, y: 0, width: 4, height: 4 }, &Rect { x: 2, y: 1, width: 4, height: 4 }), 6);
    }

    #[test]
    fn pixel_errors_are_the_terms_of_mse() {
        let p = ivp_core::RgbImage::filled(2, 1, [0.0; 3]);
        let t = ivp_core::RgbImage::from_pixels(2, 1, vec![[0.0; 3], [1.0, 0.0, 0.0]]);
        assert_eq!(pixel_errors(&p, &t), vec![0.0, 255.0 * 255.0 / 3.0]);
    }
}
