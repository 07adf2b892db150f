//! The classical methods: `copy`, `warp`, `fill` and `oracle` (`telea` has its own file).

use crate::geometry::PixelClass;
use crate::infill::rules::{copy_along_vectors, fill_disocclusions_background, fill_new_regions};
use crate::infill::telea::Telea;
use crate::infill::{infilled_in_one_stage, timed, InfillContext, InfillError, Infilled, Infiller};
use crate::prior::estimate_fictitious_vectors_on;

/// The names of the classical methods, as on the command line.
pub const CLASSICAL_METHODS: &[&str] = &["copy", "warp", "fill", "oracle", "telea"];

/// The classical method called `name`, or `None` for any other name.
pub fn classical_infiller(name: &str) -> Option<Box<dyn Infiller>> {
    match name {
        "copy" => Some(Box::new(CopyLast)),
        "warp" => Some(Box::new(WarpOnly)),
        "fill" => Some(Box::new(BackgroundFill)),
        "oracle" => Some(Box::new(Oracle)),
        "telea" => Some(Box::new(Telea::default())),
        _ => None,
    }
}

/// `copy`: the last rendered frame as it is (no warp, no new-region rule).
#[derive(Clone, Copy, Debug, Default)]
pub struct CopyLast;

impl Infiller for CopyLast {
    fn name(&self) -> &str {
        "copy"
    }

    fn uses_warp(&self) -> bool {
        false
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let (image, elapsed) = timed(|| ctx.last.image.clone());
        Ok(infilled_in_one_stage(image, elapsed))
    }
}

/// `warp`: the warped frame with black disocclusions and the common new-region rule.
#[derive(Clone, Copy, Debug, Default)]
pub struct WarpOnly;

impl Infiller for WarpOnly {
    fn name(&self) -> &str {
        "warp"
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let warped = ctx.warped;
        let (image, elapsed) = timed(|| {
            let mut image = warped.image.clone();
            // Holes of a warp are already black; say so here rather than rely on it.
            for (p, class) in image.pixels_mut().iter_mut().zip(warped.holes.classes()) {
                if *class == PixelClass::Disocclusion {
                    *p = [0.0; 3];
                }
            }
            fill_new_regions(&mut image, &warped.holes);
            image
        });
        Ok(infilled_in_one_stage(image, elapsed))
    }
}

/// `fill`: every disocclusion copies its background neighbour ([`fill_disocclusions_background`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct BackgroundFill;

impl Infiller for BackgroundFill {
    fn name(&self) -> &str {
        "fill"
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let warped = ctx.warped;
        let (image, elapsed) = timed(|| {
            let mut image = warped.image.clone();
            fill_disocclusions_background(&mut image, &warped.depth, &warped.holes);
            fill_new_regions(&mut image, &warped.holes);
            image
        });
        Ok(infilled_in_one_stage(image, elapsed))
    }
}

/// `oracle`: the fictitious vectors of ALGORITHMS.md §6.2 measured on the target frame itself, i.e. the
/// best a vector predictor restricted to the four directions could do. Disocclusions where no
/// direction matches (vector 0) take the `fill` value. Reads the ground truth.
#[derive(Clone, Copy, Debug, Default)]
pub struct Oracle;

impl Infiller for Oracle {
    fn name(&self) -> &str {
        "oracle"
    }

    fn uses_ground_truth(&self) -> bool {
        true
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let ground_truth = ctx.ground_truth.ok_or(InfillError::NeedsGroundTruth("oracle"))?;
        let warped = ctx.warped;
        if !ground_truth.same_size(&warped.image) {
            return Err(InfillError::SizeMismatch {
                what: "the ground truth",
                found: (ground_truth.width(), ground_truth.height()),
                expected: (warped.image.width(), warped.image.height()),
            });
        }
        let holes = &warped.holes;
        let (vectors, prior_elapsed) =
            timed(|| estimate_fictitious_vectors_on(&holes.known(), &holes.disocclusions(), ground_truth));
        let (image, infill_elapsed) = timed(|| {
            let mut image = warped.image.clone();
            // `fill` everywhere first, then the vectors overwrite where they exist: both read
            // known pixels only, so this equals "fill where the vector is 0".
            fill_disocclusions_background(&mut image, &warped.depth, holes);
            copy_along_vectors(&mut image, &warped.image, &vectors);
            fill_new_regions(&mut image, holes);
            image
        });
        // Zero where no direction matched: those pixels took the `fill` value instead.
        let stages = vec![("prior", prior_elapsed), ("infill", infill_elapsed)];
        Ok(Infilled { image, stages, vectors: Some(vectors) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{DepthMap, FrameView, HoleMask, Image, Intrinsics, Pixel, RgbImage, Warp, WorldToCamera};
    use crate::test_scene::{self, assert_all_finite, labelled, BoxWarp, RED};

    /// The disocclusion pixels of `warp`, row by row.
    fn disocclusions(warp: &Warp) -> Vec<Pixel> {
        let (w, h) = (warp.image.width(), warp.image.height());
        (0..h).flat_map(|v| (0..w).map(move |u| (u, v))).filter(|&(u, v)| warp.holes.is_disocclusion(u, v)).collect()
    }

    fn run(name: &str, ctx: &InfillContext<'_>) -> Infilled {
        classical_infiller(name).unwrap().infill(ctx).unwrap()
    }

    #[test]
    fn classical_methods_on_a_box_scene() {
        let scene = BoxWarp::new();
        let holes = disocclusions(&scene.warped);
        assert!(holes.len() > 50, "the scene should open a disocclusion, got {}", holes.len());
        let ctx = scene.context(false, true);
        let truth = &scene.target.0;

        let copy = run("copy", &ctx);
        assert_eq!(copy.image, scene.last.0);

        let warp = run("warp", &ctx);
        assert!(holes.iter().all(|&(u, v)| warp.image.get(u, v) == [0.0; 3]));

        // The uncovered wall takes wall colour, never the box's.
        let fill = run("fill", &ctx);
        assert!(holes.iter().all(|&(u, v)| fill.image.get(u, v) != test_scene::BOX_COLOUR));

        // The wall's stripes run along rows: where the oracle finds a vector it reproduces the truth
        // exactly; elsewhere (next to the box, whose patches match nothing) it falls back to `fill`.
        let oracle = run("oracle", &ctx);
        let known = scene.warped.holes.known();
        let vectors = estimate_fictitious_vectors_on(&known, &scene.warped.holes.disocclusions(), truth);
        let mut with_vector = 0;
        for &(u, v) in &holes {
            if vectors.get(u, v) == [0.0, 0.0] {
                assert_eq!(oracle.image.get(u, v), fill.image.get(u, v), "({u}, {v})");
            } else {
                // Splatting divides by the accumulated weight: equal up to rounding.
                let (got, want) = (oracle.image.get(u, v), truth.get(u, v));
                assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-5), "({u}, {v}): {got:?} vs {want:?}");
                with_vector += 1;
            }
        }
        assert!(with_vector * 2 >= holes.len(), "vectors on only {with_vector} of {} pixels", holes.len());
        let stage_names: Vec<&str> = oracle.stages.iter().map(|(name, _)| *name).collect();
        assert_eq!(stage_names, ["prior", "infill"]);

        // Telea inpainting fills the disocclusions and leaves known pixels as they are.
        let telea = run("telea", &ctx);
        for (i, class) in scene.warped.holes.classes().iter().enumerate() {
            if *class == PixelClass::Known {
                assert_eq!(telea.image.pixels()[i], scene.warped.image.pixels()[i]);
            }
        }
        assert!(holes.iter().all(|&(u, v)| telea.image.get(u, v) != [0.0; 3]));

        // New regions (right border) are filled the same way by every method that warps.
        for out in [&warp, &fill, &oracle, &telea] {
            for (i, class) in scene.warped.holes.classes().iter().enumerate() {
                if *class == PixelClass::NewRegion {
                    assert_eq!(out.image.pixels()[i], fill.image.pixels()[i]);
                    assert_ne!(out.image.pixels()[i], [0.0; 3]);
                }
            }
            assert_all_finite(&out.image);
        }
    }

    #[test]
    fn oracle_follows_the_matching_texture_where_fill_follows_depth() {
        // Disocclusion at columns 5..=9, rows 2..=6. The truth continues the right side's row
        // stripes into the hole, but the left side is farther: `fill` copies the left texture,
        // the oracle's vectors find the right one.
        let (w, h) = (15, 9);
        let is_hole = |u: usize, v: usize| (5..=9).contains(&u) && (2..=6).contains(&v);
        let stripes = |v: usize| [0.05 * v as f32, 0.1, 0.0];
        let truth = Image::from_fn(w, h, |u, v| if u < 5 { [1.0, 1.0, 1.0] } else { stripes(v) });
        let known: Vec<bool> = (0..w * h).map(|i| !is_hole(i % w, i / w)).collect();
        let image = Image::from_fn(w, h, |u, v| if is_hole(u, v) { [0.0; 3] } else { truth.get(u, v) });
        let depth = Image::from_fn(w, h, |u, v| {
            [if is_hole(u, v) {
                0.0
            } else if u < 5 {
                10.0
            } else {
                1.0
            }]
        });
        let warped = warp_of(image, depth, &known);
        assert_eq!(warped.holes.count(PixelClass::Disocclusion), 25);
        let outputs = run_every_method(&warped, &truth);
        let (fill, oracle) = (&outputs[2].image, &outputs[3].image);
        for v in 2..=6 {
            // Column 7 on: the hole pixel's patch is all stripes, as is the right candidate's.
            for u in 7..=9 {
                assert_eq!(oracle.get(u, v), truth.get(u, v), "({u}, {v})");
                assert_eq!(fill.get(u, v), truth.get(4, v), "({u}, {v})");
            }
            // Columns 5, 6: the patch straddles both textures, no candidate is close: `fill`.
            for u in 5..=6 {
                assert_eq!(oracle.get(u, v), fill.get(u, v), "({u}, {v})");
            }
        }
    }

    #[test]
    fn oracle_needs_the_ground_truth_and_says_so() {
        let scene = BoxWarp::new();
        let oracle = classical_infiller("oracle").unwrap();
        assert!(oracle.uses_ground_truth());
        assert!(matches!(oracle.infill(&scene.context(false, false)), Err(InfillError::NeedsGroundTruth("oracle"))));
        let small = Image::filled(3, 3, RED);
        let ctx = InfillContext { ground_truth: Some(&small), ..scene.context(false, false) };
        assert!(matches!(oracle.infill(&ctx), Err(InfillError::SizeMismatch { what: "the ground truth", .. })));
    }

    #[test]
    fn registry_knows_exactly_the_classical_methods() {
        for &name in CLASSICAL_METHODS {
            let method = classical_infiller(name).unwrap();
            assert_eq!(method.name(), name);
            assert_eq!(method.uses_ground_truth(), name == "oracle");
        }
        assert!(classical_infiller("ivp").is_none());
        assert!(classical_infiller("").is_none());
    }

    /// A warp with the given image, depth and known mask, as the warper would return it.
    fn warp_of(image: RgbImage, depth: DepthMap, known: &[bool]) -> Warp {
        let holes = HoleMask::classify(image.width(), image.height(), known);
        Warp { image, depth, holes }
    }

    fn run_every_method(warped: &Warp, truth: &RgbImage) -> Vec<Infilled> {
        let k = Intrinsics::new(10.0, 10.0, 3.0, 2.0);
        let pose = WorldToCamera(glam::DMat4::IDENTITY);
        let ctx = InfillContext {
            intrinsics: &k,
            last: FrameView { image: truth, depth: &warped.depth, pose: &pose },
            before_last: None,
            target_pose: &pose,
            warped,
            ground_truth: Some(truth),
        };
        CLASSICAL_METHODS.iter().map(|name| run(name, &ctx)).collect()
    }

    #[test]
    fn all_hole_and_no_hole_frames_of_odd_size() {
        let (w, h) = (7, 5);
        let truth = labelled(w, h);
        // No holes: every warping method returns the warp untouched.
        let full = warp_of(truth.clone(), Image::filled(w, h, [3.0]), &vec![true; w * h]);
        for out in run_every_method(&full, &truth) {
            assert_eq!(out.image, truth);
        }
        // All holes: nothing to copy from; the warped frame (black) stays as it is.
        let empty = warp_of(Image::zeros(w, h), Image::zeros(w, h), &vec![false; w * h]);
        for out in &run_every_method(&empty, &truth)[1..] {
            assert!(out.image.as_flat().iter().all(|&x| x == 0.0));
        }
    }

    #[test]
    fn constant_scene_is_reproduced_by_every_method() {
        let (w, h) = (9, 7);
        let grey = [0.4, 0.4, 0.4];
        let truth = Image::filled(w, h, grey);
        // A disocclusion block in the middle and a new region on the right.
        let known: Vec<bool> =
            (0..w * h).map(|i| !((3..6).contains(&(i % w)) && (2..5).contains(&(i / w))) && i % w != w - 1).collect();
        let image = Image::from_fn(w, h, |u, v| if known[v * w + u] { grey } else { [0.0; 3] });
        let depth = Image::from_fn(w, h, |u, v| [if known[v * w + u] { 2.0 } else { 0.0 }]);
        let warped = warp_of(image, depth, &known);
        assert!(warped.holes.count(PixelClass::Disocclusion) == 9);
        let outputs = run_every_method(&warped, &truth);
        for (name, out) in CLASSICAL_METHODS.iter().zip(&outputs) {
            for v in 0..h {
                for u in 0..w {
                    let want = if *name == "warp" && warped.holes.is_disocclusion(u, v) { [0.0; 3] } else { grey };
                    assert_eq!(out.image.get(u, v), want, "{name} at ({u}, {v})");
                }
            }
        }
    }

    #[test]
    fn no_nan_from_nan_inputs() {
        let (w, h) = (11, 9);
        let truth = Image::from_fn(w, h, |u, v| if (u + v) % 4 == 0 { [f32::NAN; 3] } else { [0.5, 0.2, 0.9] });
        let known: Vec<bool> = (0..w * h).map(|i| !(4..7).contains(&(i % w)) || i / w == 0 || i / w == h - 1).collect();
        let image = Image::from_fn(w, h, |u, v| if known[v * w + u] { [0.1, 0.2, 0.3] } else { [0.0; 3] });
        let depth = Image::from_fn(w, h, |u, v| {
            [if !known[v * w + u] {
                0.0
            } else if u % 3 == 0 {
                f32::NAN
            } else {
                1.0 + u as f32
            }]
        });
        let warped = warp_of(image, depth, &known);
        assert!(warped.holes.count(PixelClass::Disocclusion) > 0);
        // `copy` returns the NaN-laden last frame as it is: skip it.
        for out in &run_every_method(&warped, &truth)[1..] {
            assert_all_finite(&out.image);
        }
    }
}
