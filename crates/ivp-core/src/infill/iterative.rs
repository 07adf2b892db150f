//! Iterative infilling at test time (ALGORITHMS.md §6.5).
//!
//! A [`VectorPredictor`] (the network) predicts an infilling vector for every disocclusion pixel
//! still to fill; each pixel reads colour and depth at the vector's target with the
//! known-pixels-only bilinear read (ALGORITHMS.md §6.3). In iterations `1..P-1` a vector is kept only if the
//! depth it reads is at least the pixel's background depth threshold; kept pixels become known
//! (later iterations may read them, so vectors compose) and their vectors become the prior of the
//! next prediction. The last iteration keeps every vector, walks the ones that read nothing along
//! their direction, and falls back to the `fill` rule where even that fails or where the read lands
//! on an object far in front of the pixel's background ([`FOREGROUND_DEPTH_RATIO`]). New regions
//! are filled by the common rule of ALGORITHMS.md §4.1 at the end.
//!
//! Everything is deterministic: each iteration computes the outcome of every hole pixel from the
//! state before it (in parallel over pixels), then applies them all.

use std::sync::Arc;
use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::geometry::{DepthMap, HoleMask, KnownRead, NearestKnown, Pixel, PixelClass, RgbImage, VectorField};
use crate::infill::far_blur::{blur_far_pixels, FAR_BLUR};
use crate::infill::rules::{background_source, distance_to_known, fill_new_regions_with, thin_run_source, THIN_RUN};
use crate::infill::InfillError;
use crate::prior::{background_depth_thresholds_at, ScaledPrior};

/// P of ALGORITHMS.md §6.5: two iterations that keep background vectors only, then the last.
pub const DEFAULT_ITERATIONS: usize = 3;

/// The largest magnitude, in pixels, that the last iteration tries along a vector's direction.
pub const MAX_WALK_MAGNITUDE: usize = 100;

/// The last iteration refuses a read whose depth is less than the pixel's background depth
/// threshold divided by this: a disocclusion reveals background, and a read four times nearer
/// than the midpoint of its near and far neighbours lands on the object that covered it. The
/// pixel takes the `fill` value instead. Reads between that and the threshold are kept as the
/// reference keeps them: at 320x240 they are mostly right (sides of objects revealed at their own
/// depth; refusing all of them costs 23% D-MSE on the Blender clips, those below half the
/// threshold 2%), while at 1080p the foreground reads sit at 0.13-0.16 of the threshold
/// (results/recipe-hd/README.md, "The last iteration's foreground guard").
pub const FOREGROUND_DEPTH_RATIO: f32 = 4.0;

/// Hole pixels per rayon task when deciding the outcomes of an iteration.
const PIXELS_PER_TASK: usize = 256;

// ---------------------------------------------------------------------------------------------
// The predictor
// ---------------------------------------------------------------------------------------------

/// The neural network behind infilling vector prediction, on whole images.
pub trait VectorPredictor: Send + Sync {
    /// Infilling vectors for the pixels marked in `holes`.
    ///
    /// - `prior`: the temporal prior (zeros where there is none); in later iterations it also
    ///   holds the vectors kept so far at the pixels they filled.
    /// - `depth`: the warped depth, 0 at every pixel not known yet (holes still to fill and new
    ///   regions); pixels filled by earlier iterations hold the depth they read.
    /// - `holes`: row-major, `true` = a disocclusion pixel still to fill. Never all `false`: the
    ///   predictor is not called when there is nothing to predict.
    ///
    /// Returns vectors in pixels (channel 0 = column offset, 1 = row offset), of the size of
    /// `depth`. Values outside `holes` are ignored (they should be zero).
    fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError>;

    /// [`VectorPredictor::predict`] as the iterative infilling calls it: with the prior at the
    /// scale it was measured on, writing the vectors at the pixels of `holes` into `out` (of the
    /// size of `depth`) and nothing else. The infilling predicts into its output field, whose
    /// other pixels hold the vectors of earlier iterations, so that no frame-sized field is
    /// allocated or cleared per call; and a predictor that reads the prior at its scale (the
    /// network) never sees it at full size. By default, `predict` of the full-size prior, copied
    /// at the holes.
    fn predict_into(
        &self,
        prior: &ScaledPrior,
        depth: &DepthMap,
        holes: &[bool],
        out: &mut VectorField,
    ) -> Result<(), InfillError> {
        let vectors = self.predict(&prior.to_full(), depth, holes)?;
        if !vectors.same_size(out) {
            return Err(size_error(
                "the predicted vector field",
                vectors.width(),
                vectors.height(),
                out.width(),
                out.height(),
            ));
        }
        let pixels = out.pixels_mut().iter_mut().zip(vectors.pixels()).zip(holes);
        pixels.filter(|(_, &hole)| hole).for_each(|((out, vector), _)| *out = *vector);
        Ok(())
    }
}

/// A predictor behind a pointer is the predictor itself.
macro_rules! forward_vector_predictor {
    ($($pointer:ty),*) => {$(
        impl<T: VectorPredictor + ?Sized> VectorPredictor for $pointer {
            fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
                (**self).predict(prior, depth, holes)
            }

            fn predict_into(
                &self,
                prior: &ScaledPrior,
                depth: &DepthMap,
                holes: &[bool],
                out: &mut VectorField,
            ) -> Result<(), InfillError> {
                (**self).predict_into(prior, depth, holes, out)
            }
        }
    )*};
}

forward_vector_predictor!(&T, Box<T>, Arc<T>);

// ---------------------------------------------------------------------------------------------
// Iterative infilling
// ---------------------------------------------------------------------------------------------

/// The rules around the network's passes: thin runs filled before them (`thin_run`, the longest
/// run, 0: none; [`thin_run_source`]) and the far blur after them (`far_blur`, its strength, 0:
/// none; ALGORITHMS.md §6.5). Neither is in the paper: the default is the recipe's,
/// [`InfillRules::NONE`] the paper's infilling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InfillRules {
    pub thin_run: usize,
    pub far_blur: f32,
}

impl InfillRules {
    /// The network's passes alone, as the paper infills.
    pub const NONE: InfillRules = InfillRules { thin_run: 0, far_blur: 0.0 };
}

impl Default for InfillRules {
    fn default() -> Self {
        InfillRules { thin_run: THIN_RUN, far_blur: FAR_BLUR }
    }
}

/// The result of [`infill_iteratively`].
#[derive(Clone, Debug)]
pub struct IterativeInfill {
    /// The whole frame: known pixels as warped, disocclusions infilled, new regions by the common
    /// rule of ALGORITHMS.md §4.1.
    pub image: RgbImage,
    /// Per disocclusion pixel, the vector it was filled with, from the pixel to the position it
    /// read in the iteration that filled it (which may be a pixel filled earlier): the predicted
    /// vector, or in the last iteration the rescaled one when it had to walk. Pixels that fell
    /// back to `fill` hold the vector to the pixel `fill` copied (zero if none). Zero elsewhere.
    pub vectors: VectorField,
    /// [`Self::vectors`] composed through the iterations: from each disocclusion pixel to the
    /// (bilinearly averaged) position among the originally known pixels that its colour comes
    /// from. Equal to `vectors` for pixels that read originally known pixels only.
    pub composed_vectors: VectorField,
    /// Disocclusion pixels in thin runs, filled before the first iteration by the rule of
    /// [`thin_run_source`].
    pub thin_runs: usize,
    /// Disocclusion pixels filled by each iteration (`len() == iterations`); the last entry counts
    /// the walked and fallen-back pixels too. Iterations that had nothing left to fill count 0.
    pub filled_per_iteration: Vec<usize>,
    /// Pixels of the last iteration whose own target had no known corner, that found one along
    /// their direction.
    pub walked: usize,
    /// Pixels of the last iteration that took the `fill` value: they found no known pixel along
    /// their direction, had a zero or non-finite vector, or read a foreground object
    /// (`foreground_reads` of them).
    pub fell_back: usize,
    /// Pixels of the last iteration whose read was refused as foreground ([`FOREGROUND_DEPTH_RATIO`]).
    pub foreground_reads: usize,
    /// How many times the predictor was called.
    pub predictions: usize,
    /// Time spent inside [`VectorPredictor::predict`].
    pub predict_time: Duration,
    /// Time spent in everything else (thresholds, reads, bookkeeping, new regions).
    pub other_time: Duration,
}

/// What happens to one hole pixel in one iteration.
#[derive(Clone, Copy, Debug)]
enum Outcome {
    /// Still a hole after this iteration.
    Hole,
    /// Filled by reading at `pixel + vector`.
    Read { vector: [f32; 2], colour: [f32; 3], depth: f32, source: [f32; 2], walked: bool },
    /// The last iteration found nothing to read, or read the foreground: the `fill` value.
    Fill { foreground: bool },
}

/// What the reads of one iteration see: it changes between iterations only.
struct State<'a> {
    width: usize,
    height: usize,
    /// Known pixels as warped, filled pixels as read.
    image: &'a RgbImage,
    /// Warped depth, 0 where not known (the predictor's input), filled pixels as read.
    depth: &'a DepthMap,
    known: &'a [bool],
    original_known: &'a [bool],
    /// For each filled pixel, the position among the originally known pixels its colour comes
    /// from: the composition of the vectors (an originally known pixel is its own source).
    source: &'a [[f32; 2]],
}

impl State<'_> {
    /// Colour, depth and composed source of a read.
    #[inline]
    fn read(&self, read: &KnownRead) -> ([f32; 3], f32, [f32; 2]) {
        let w = self.width;
        let source =
            read.read_by(|i| if self.original_known[i] { [(i % w) as f32, (i / w) as f32] } else { self.source[i] });
        (read.read(self.image), read.read(self.depth)[0], source)
    }
}

fn size_error(what: &'static str, w: usize, h: usize, width: usize, height: usize) -> InfillError {
    InfillError::SizeMismatch { what, found: (w, h), expected: (width, height) }
}

/// ALGORITHMS.md §6.5 on the disocclusion pixels of `holes`, then the common new-region rule (ALGORITHMS.md §4.1)
/// so that the whole frame is filled.
///
/// - The background depth threshold of each disocclusion pixel is computed once, on the original
///   known mask and `warped_depth` ([`crate::prior::background_depth_threshold`]).
/// - Iterations `1..P-1`: predict; read colour and depth at each vector's target over the known
///   corners; keep the vector if a corner was found and the depth read is at least the threshold
///   (no threshold: keep). Kept pixels become known with the colour and depth read, and their
///   vector replaces the prior at that pixel for the next prediction (the prior elsewhere,
///   including at rejected pixels, is left as it was).
/// - Last iteration: keep every vector. One whose target has no known corner keeps its direction
///   and takes the smallest magnitude `m` in `1..=100` (whole pixels, increasing) at which the read
///   finds a known corner. A pixel whose vector is zero or not finite, or finds nothing, takes the
///   `fill` value: the pixel [`background_source`] picks on the original known mask and
///   `warped_depth` (left as warped if there is none).
/// - Within an iteration all pixels read the state before it; across iterations reads compose (a
///   pixel filled in iteration 2 may read one filled in 1).
///
/// - `rules`: thin runs of up to `rules.thin_run` pixels are filled before the first iteration
///   and seen known by it; after the last, the infilled disocclusions are blurred by
///   `rules.far_blur` ([`blur_far_pixels`], each pixel at its [`distance_to_known`]).
///
/// `P = iterations` must be at least 1 (`P = 1` is the last-iteration rule alone). The predictor
/// is not called once no disocclusion pixel is left (so never for a frame without any).
/// `prior` is the temporal prior, zeros where there is none.
pub fn infill_iteratively(
    predictor: &dyn VectorPredictor,
    warped: &RgbImage,
    warped_depth: &DepthMap,
    holes: &HoleMask,
    prior: &ScaledPrior,
    iterations: usize,
    rules: InfillRules,
) -> Result<IterativeInfill, InfillError> {
    let start = Instant::now();
    let (w, h) = (warped.width(), warped.height());
    if iterations == 0 {
        return Err(InfillError::NoIterations);
    }
    if !warped_depth.same_size(warped) {
        return Err(size_error("the warped depth", warped_depth.width(), warped_depth.height(), w, h));
    }
    if holes.width() != w || holes.height() != h {
        return Err(size_error("the hole mask", holes.width(), holes.height(), w, h));
    }
    if (prior.width(), prior.height()) != (w, h) {
        return Err(size_error("the prior", prior.width(), prior.height(), w, h));
    }

    let disocclusions = holes.indices_of(PixelClass::Disocclusion);
    let mut remaining = disocclusions.clone();
    let original_known = holes.known();
    // The search structure of the original known mask (it serves the thresholds, the `fill`
    // fallback and the new regions) is built while the frame's buffers are copied: the copies
    // are each one thread's work at memory speed, and at 1080p took as long as the search.
    let ((nearest, mut thresholds), (outputs, working)) = rayon::join(
        || {
            let nearest = NearestKnown::new(w, h, &original_known);
            // Aligned with `remaining`, and shrunk with it.
            let thresholds = background_depth_thresholds_at(&nearest, warped_depth, &remaining);
            (nearest, thresholds)
        },
        || {
            rayon::join(
                || Outputs::new(warped),
                || (!remaining.is_empty()).then(|| Working::new(warped_depth, prior, &original_known, &remaining)),
            )
        },
    );
    let mut out = IterativeInfill {
        image: outputs.image,
        vectors: outputs.vectors,
        // Made from the composed sources once every pixel is filled (below).
        composed_vectors: VectorField::zeros(0, 0),
        thin_runs: 0,
        filled_per_iteration: vec![0; iterations],
        walked: 0,
        fell_back: 0,
        foreground_reads: 0,
        predictions: 0,
        predict_time: Duration::ZERO,
        other_time: Duration::ZERO,
    };
    if let Some(Working { depth: mut depth_map, mut known, mut sources, mut prior, mut to_fill }) = working {
        // Thin runs first: they copy their background neighbour, and the passes see them known.
        let thin: Vec<Option<Pixel>> = remaining
            .par_iter()
            .with_min_len(PIXELS_PER_TASK)
            .map(|&i| thin_run_source(&nearest, warped_depth, (i % w, i / w), rules.thin_run))
            .collect();
        let (mut wide, mut wide_thresholds) = (Vec::new(), Vec::new());
        for ((&i, &threshold), source) in remaining.iter().zip(&thresholds).zip(thin) {
            let Some(q) = source else {
                wide.push(i);
                wide_thresholds.push(threshold);
                continue;
            };
            let vector = [q.0 as f32 - (i % w) as f32, q.1 as f32 - (i / w) as f32];
            out.image.pixels_mut()[i] = warped.get(q.0, q.1);
            out.vectors.pixels_mut()[i] = vector;
            depth_map.pixels_mut()[i] = [warped_depth.at(q.0, q.1)];
            sources[i] = [q.0 as f32, q.1 as f32];
            prior.set(i, vector);
            known[i] = true;
            to_fill[i] = false;
            out.thin_runs += 1;
        }
        (remaining, thresholds) = (wide, wide_thresholds);
        for (iteration, filled) in out.filled_per_iteration.iter_mut().enumerate() {
            if remaining.is_empty() {
                break;
            }
            let last = iteration + 1 == iterations;
            let predict_start = Instant::now();
            // The vectors of the pixels still to fill land in the output field; the loop below
            // overwrites each of them with the vector that filled it, if any.
            predictor.predict_into(&prior, &depth_map, &to_fill, &mut out.vectors)?;
            out.predict_time += predict_start.elapsed();
            out.predictions += 1;

            let state = State {
                width: w,
                height: h,
                image: &out.image,
                depth: &depth_map,
                known: &known,
                original_known: &original_known,
                source: &sources,
            };
            let outcomes: Vec<Outcome> = remaining
                .par_iter()
                .zip(&thresholds)
                .with_min_len(PIXELS_PER_TASK)
                .map(|(&i, &threshold)| {
                    let vector = out.vectors.pixels()[i];
                    if last {
                        last_outcome(&state, (i % w, i / w), vector, threshold)
                    } else {
                        early_outcome(&state, (i % w, i / w), vector, threshold)
                    }
                })
                .collect();

            let (mut still_holes, mut still_thresholds) = (Vec::new(), Vec::new());
            for ((&i, &threshold), outcome) in remaining.iter().zip(&thresholds).zip(&outcomes) {
                let p = (i % w, i / w);
                let offset = |[x, y]: [f32; 2]| [x - p.0 as f32, y - p.1 as f32];
                match *outcome {
                    Outcome::Hole => {
                        still_holes.push(i);
                        still_thresholds.push(threshold);
                        continue;
                    }
                    Outcome::Read { vector, colour, depth, source, walked } => {
                        out.image.pixels_mut()[i] = colour;
                        out.vectors.pixels_mut()[i] = vector;
                        out.walked += usize::from(walked);
                        depth_map.pixels_mut()[i] = [depth];
                        sources[i] = source;
                        prior.set(i, vector);
                    }
                    Outcome::Fill { foreground } => {
                        // The source `fill` copied, else the pixel itself (a composed vector of 0).
                        // Only the last iteration falls back, so no read sees this source.
                        let q = background_source(&nearest, warped_depth, p);
                        if let Some(q) = q {
                            out.image.pixels_mut()[i] = warped.get(q.0, q.1);
                        }
                        // (Over the prediction the field held.)
                        out.vectors.pixels_mut()[i] = q.map_or([0.0, 0.0], |q| offset([q.0 as f32, q.1 as f32]));
                        let q = q.unwrap_or(p);
                        sources[i] = [q.0 as f32, q.1 as f32];
                        out.fell_back += 1;
                        out.foreground_reads += usize::from(foreground);
                    }
                }
                known[i] = true;
                to_fill[i] = false;
                *filled += 1;
            }
            (remaining, thresholds) = (still_holes, still_thresholds);
        }
        debug_assert!(remaining.is_empty(), "the last iteration fills every pixel");
        // Each filled pixel's composed vector is its source less its position (0 elsewhere):
        // made in the sources' own buffer rather than in one more frame-sized field.
        for &i in &disocclusions {
            let (p, [x, y]) = ((i % w, i / w), sources[i]);
            sources[i] = [x - p.0 as f32, y - p.1 as f32];
        }
        out.composed_vectors = VectorField::from_pixels(w, h, sources);
        let distances: Vec<f32> = disocclusions
            .par_iter()
            .with_min_len(PIXELS_PER_TASK)
            .map(|&i| distance_to_known(&nearest, (i % w, i / w)))
            .collect();
        blur_far_pixels(&mut out.image, &disocclusions, &distances, rules.far_blur);
    } else {
        out.composed_vectors = VectorField::zeros(w, h);
    }

    fill_new_regions_with(&mut out.image, holes, &nearest);
    out.other_time = start.elapsed().saturating_sub(out.predict_time);
    Ok(out)
}

/// The frame-sized outputs before the first iteration: the warped frame, and the vectors (zero;
/// each iteration's predictions land in them at the pixels still to fill).
struct Outputs {
    image: RgbImage,
    vectors: VectorField,
}

impl Outputs {
    fn new(warped: &RgbImage) -> Self {
        let (w, h) = (warped.width(), warped.height());
        let (image, vectors) = rayon::join(|| warped.clone(), || VectorField::zeros(w, h));
        Self { image, vectors }
    }
}

/// What the iterations update and the predictor reads, before the first iteration (see
/// [`State`]): built side by side, each a copy at memory speed.
struct Working {
    /// The warped depth, 0 where not known.
    depth: DepthMap,
    known: Vec<bool>,
    sources: Vec<[f32; 2]>,
    prior: ScaledPrior,
    /// The disocclusion pixels still to fill.
    to_fill: Vec<bool>,
}

impl Working {
    fn new(warped_depth: &DepthMap, prior: &ScaledPrior, original_known: &[bool], remaining: &[usize]) -> Self {
        let n = original_known.len();
        let depth_where_known = || {
            let depths = warped_depth.pixels().iter().zip(original_known);
            let pixels = depths.map(|(&z, &k)| if k { z } else { [0.0] }).collect();
            DepthMap::from_pixels(warped_depth.width(), warped_depth.height(), pixels)
        };
        let to_fill = || {
            let mut to_fill = vec![false; n];
            remaining.iter().for_each(|&i| to_fill[i] = true);
            to_fill
        };
        let ((depth, known), ((sources, prior), to_fill)) = rayon::join(
            || rayon::join(depth_where_known, || original_known.to_vec()),
            || rayon::join(|| rayon::join(|| vec![[0f32; 2]; n], || prior.clone()), to_fill),
        );
        Self { depth, known, sources, prior, to_fill }
    }
}

/// Iterations `1..P-1`: keep the vector if it reads a known corner at depth >= the threshold.
#[inline]
fn early_outcome(state: &State, p: Pixel, vector: [f32; 2], threshold: Option<f32>) -> Outcome {
    let (x, y) = (p.0 as f32 + vector[0], p.1 as f32 + vector[1]);
    let Some(read) = KnownRead::at(state.width, state.height, state.known, x, y) else { return Outcome::Hole };
    let [depth] = read.read(state.depth);
    // A NaN depth fails the comparison: never kept against a threshold.
    let keep = threshold.is_none_or(|t| depth >= t);
    if !keep {
        return Outcome::Hole;
    }
    let (colour, depth, source) = state.read(&read);
    Outcome::Read { vector, colour, depth, source, walked: false }
}

/// The last iteration: the vector as it is, else walked along its direction, else `fill`; `fill`
/// too where the read lands on the foreground ([`FOREGROUND_DEPTH_RATIO`]).
#[inline]
fn last_outcome(state: &State, p: Pixel, vector: [f32; 2], threshold: Option<f32>) -> Outcome {
    let outcome = read_or_walk(state, p, vector);
    match (outcome, threshold) {
        (Outcome::Read { depth, .. }, Some(t)) if depth * FOREGROUND_DEPTH_RATIO < t => {
            Outcome::Fill { foreground: true }
        }
        _ => outcome,
    }
}

/// The read at `p + vector`, else the first along the vector's direction, else `fill`.
#[inline]
fn read_or_walk(state: &State, p: Pixel, vector: [f32; 2]) -> Outcome {
    let read_at = |vector: [f32; 2], walked: bool| {
        let (x, y) = (p.0 as f32 + vector[0], p.1 as f32 + vector[1]);
        let read = KnownRead::at(state.width, state.height, state.known, x, y)?;
        let (colour, depth, source) = state.read(&read);
        Some(Outcome::Read { vector, colour, depth, source, walked })
    };
    if let Some(outcome) = read_at(vector, false) {
        return outcome;
    }
    let [a, b] = vector.map(f64::from);
    let length = a.hypot(b);
    // In f64 the length of any finite f32 vector is finite; zero or NaN has no direction.
    if !(length.is_finite() && length > 0.0) {
        return Outcome::Fill { foreground: false };
    }
    let (da, db) = (a / length, b / length);
    (1..=MAX_WALK_MAGNITUDE)
        .find_map(|m| read_at([(m as f64 * da) as f32, (m as f64 * db) as f32], true))
        .unwrap_or(Outcome::Fill { foreground: false })
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use super::*;
    use crate::geometry::image::is_valid_depth;
    use crate::geometry::{sample_known, Direction, Image, Warp};
    use crate::infill::rules::{fill_disocclusions_background, fill_new_regions};
    use crate::test_scene::{self, BoxWarp};

    /// A predictor made of a closure.
    struct FnPredictor<F>(F);

    impl<F> VectorPredictor for FnPredictor<F>
    where
        F: Fn(&VectorField, &DepthMap, &[bool]) -> VectorField + Send + Sync,
    {
        fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
            Ok((self.0)(prior, depth, holes))
        }
    }

    /// The inputs of one call to a predictor.
    #[derive(Clone, Debug)]
    struct Call {
        prior: VectorField,
        depth: DepthMap,
        holes: Vec<bool>,
    }

    /// Wraps a predictor and records every call.
    struct Recording<P> {
        inner: P,
        calls: Mutex<Vec<Call>>,
    }

    impl<P> Recording<P> {
        fn new(inner: P) -> Self {
            Self { inner, calls: Mutex::new(Vec::new()) }
        }

        fn calls(&self) -> Vec<Call> {
            self.calls.lock().unwrap().clone()
        }
    }

    impl<P: VectorPredictor> VectorPredictor for Recording<P> {
        fn predict(&self, prior: &VectorField, depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
            assert!(holes.iter().any(|&h| h), "called with nothing to predict");
            self.calls.lock().unwrap().push(Call { prior: prior.clone(), depth: depth.clone(), holes: holes.to_vec() });
            self.inner.predict(prior, depth, holes)
        }
    }

    /// Applies `f(u, v)` at every pixel of `holes`, zero elsewhere.
    fn on_holes(depth: &DepthMap, holes: &[bool], f: impl Fn(usize, usize) -> [f32; 2]) -> VectorField {
        let w = depth.width();
        Image::from_fn(w, depth.height(), |u, v| if holes[v * w + u] { f(u, v) } else { [0.0, 0.0] })
    }

    /// Every hole pixel points to the nearest pixel along `dir` that is known now (the predictor
    /// sees the known mask as the pixels of valid depth); zero if there is none.
    fn to_nearest_known(dir: Direction) -> FnPredictor<impl Fn(&VectorField, &DepthMap, &[bool]) -> VectorField> {
        FnPredictor(move |_: &VectorField, depth: &DepthMap, holes: &[bool]| {
            let known: Vec<bool> = depth.pixels().iter().map(|&[z]| is_valid_depth(z)).collect();
            let nearest = NearestKnown::new(depth.width(), depth.height(), &known);
            on_holes(depth, holes, |u, v| {
                nearest.beyond((u, v), dir).map_or([0.0, 0.0], |(su, sv)| [su as f32 - u as f32, sv as f32 - v as f32])
            })
        })
    }

    /// Every hole pixel gets `vector`.
    fn constant(vector: [f32; 2]) -> FnPredictor<impl Fn(&VectorField, &DepthMap, &[bool]) -> VectorField> {
        FnPredictor(move |_: &VectorField, depth: &DepthMap, holes: &[bool]| on_holes(depth, holes, |_, _| vector))
    }

    /// Every hole pixel gets the vector `f(u, v)`.
    fn per_pixel(
        f: impl Fn(usize, usize) -> [f32; 2] + Send + Sync,
    ) -> FnPredictor<impl Fn(&VectorField, &DepthMap, &[bool]) -> VectorField> {
        FnPredictor(move |_: &VectorField, depth: &DepthMap, holes: &[bool]| on_holes(depth, holes, &f))
    }

    /// The passes alone: these small frames' holes are thin runs, which the tests of the thin-run
    /// rule cover.
    fn run(predictor: &dyn VectorPredictor, warp: &Warp, prior: &VectorField, iterations: usize) -> IterativeInfill {
        let prior = ScaledPrior::full_size(prior.clone());
        infill_iteratively(predictor, &warp.image, &warp.depth, &warp.holes, &prior, iterations, InfillRules::NONE)
            .unwrap()
    }

    /// The thin-run rule without the far blur.
    fn thin_only(thin_run: usize) -> InfillRules {
        InfillRules { thin_run, far_blur: 0.0 }
    }

    fn zero_prior(warp: &Warp) -> VectorField {
        VectorField::zeros(warp.image.width(), warp.image.height())
    }

    /// The output of the classical `fill` method on a warp.
    fn fill_of(warp: &Warp) -> RgbImage {
        let mut image = warp.image.clone();
        fill_disocclusions_background(&mut image, &warp.depth, &warp.holes);
        fill_new_regions(&mut image, &warp.holes);
        image
    }

    fn disocclusions(warp: &Warp) -> Vec<Pixel> {
        let (w, h) = (warp.image.width(), warp.image.height());
        (0..h).flat_map(|v| (0..w).map(move |u| (u, v))).filter(|&(u, v)| warp.holes.is_disocclusion(u, v)).collect()
    }

    fn assert_all_finite(image: &RgbImage) {
        assert!(image.as_flat().iter().all(|x| x.is_finite()), "non-finite pixel");
    }

    /// A warp with the given image, depth and known mask, as the warper would return it (black,
    /// depth 0 at holes).
    fn warp_of(
        image: impl Fn(usize, usize) -> [f32; 3],
        depth: impl Fn(usize, usize) -> f32,
        known: &[bool],
        w: usize,
        h: usize,
    ) -> Warp {
        let k = |u: usize, v: usize| known[v * w + u];
        let image = Image::from_fn(w, h, |u, v| if k(u, v) { image(u, v) } else { [0.0; 3] });
        let depth = Image::from_fn(w, h, |u, v| [if k(u, v) { depth(u, v) } else { 0.0 }]);
        Warp { image, depth, holes: HoleMask::classify(w, h, known) }
    }

    /// A distinct colour per pixel, so that a copy says where it came from.
    fn labelled(u: usize, v: usize) -> [f32; 3] {
        [u as f32 / 128.0, v as f32 / 64.0, 0.5]
    }

    #[test]
    fn background_vectors_reproduce_fill_on_the_box_scene() {
        let scene = BoxWarp::new();
        let warp = &scene.warped;
        let holes = disocclusions(warp);
        assert!(holes.len() > 50, "the scene should open a disocclusion, got {}", holes.len());
        let fill = fill_of(warp);
        // `fill` recovers the truth there (wall stripes run along rows), so matching it is the best.
        for &(u, v) in &holes {
            assert_eq!(fill.get(u, v), scene.target.0.get(u, v), "({u}, {v})");
        }
        for iterations in [1, 2, 3, 5] {
            let predictor = Recording::new(to_nearest_known(Direction::Right));
            let out = run(&predictor, warp, &zero_prior(warp), iterations);
            assert_eq!(out.image, fill, "P = {iterations}");
            // Everything is background: all kept in the first iteration (also when it is the last).
            let mut want = vec![0; iterations];
            want[0] = holes.len();
            assert_eq!(out.filled_per_iteration, want, "P = {iterations}");
            assert_eq!((out.walked, out.fell_back, out.predictions), (0, 0, 1));
            assert_eq!(predictor.calls().len(), 1);
            for &(u, v) in &holes {
                let [a, b] = out.vectors.get(u, v);
                assert!(a >= 1.0 && b == 0.0 && warp.holes.is_known(u + a as usize, v), "({u}, {v}): {a}, {b}");
                assert_eq!(out.composed_vectors.get(u, v), [a, b]);
            }
        }
    }

    #[test]
    fn foreground_vectors_are_rejected_until_the_last_iteration() {
        let scene = BoxWarp::new();
        let warp = &scene.warped;
        let holes = disocclusions(warp);
        // The box is on the left of the uncovered wall.
        for iterations in [1, 2, 3] {
            let predictor = Recording::new(to_nearest_known(Direction::Left));
            let out = run(&predictor, warp, &zero_prior(warp), iterations);
            let mut want = vec![0; iterations];
            want[iterations - 1] = holes.len();
            assert_eq!(out.filled_per_iteration, want, "P = {iterations}");
            let calls = predictor.calls();
            assert_eq!(calls.len(), iterations);
            // Rejected every time: the same holes, depth and prior in every call.
            for call in &calls {
                assert_eq!(call.holes, warp.holes.disocclusions());
                assert_eq!(call.depth, warp.depth);
                assert_eq!(call.prior, zero_prior(warp));
            }
            // The last iteration keeps them: the box colour, as predicted.
            for &(u, v) in &holes {
                assert_eq!(out.image.get(u, v), test_scene::BOX_COLOUR, "P = {iterations} at ({u}, {v})");
            }
            assert_eq!((out.walked, out.fell_back), (0, 0));
        }
        // Half the pixels right, half left: the right ones are kept at once, the left ones at the end.
        let predictor = Recording::new(FnPredictor(|prior: &VectorField, depth: &DepthMap, holes: &[bool]| {
            let right = to_nearest_known(Direction::Right).predict(prior, depth, holes).unwrap();
            let left = to_nearest_known(Direction::Left).predict(prior, depth, holes).unwrap();
            Image::from_fn(
                depth.width(),
                depth.height(),
                |u, v| if v % 2 == 0 { right.get(u, v) } else { left.get(u, v) },
            )
        }));
        let out = run(&predictor, warp, &zero_prior(warp), 3);
        let even = holes.iter().filter(|(_, v)| v % 2 == 0).count();
        assert_eq!(out.filled_per_iteration, [even, 0, holes.len() - even]);
        let fill = fill_of(warp);
        for &(u, v) in &holes {
            let want = if v % 2 == 0 { fill.get(u, v) } else { test_scene::BOX_COLOUR };
            assert_eq!(out.image.get(u, v), want, "({u}, {v})");
        }
    }

    /// 12x9, disocclusion block at columns 4..=7, rows 3..=5. Left of it depth 1 (foreground),
    /// right of it depth 5 (background), elsewhere 3: `fill` copies the right neighbour.
    fn block_scene() -> Warp {
        block_scene_at(1.0, 5.0)
    }

    /// [`block_scene`] with the foreground at depth `near` and the background at `far` (above 3).
    /// Every hole pixel has 20 threshold candidates, 5 of each depth on the left and right: its
    /// background threshold is `(near + far) / 2`.
    fn block_scene_at(near: f32, far: f32) -> Warp {
        let (w, h) = (12, 9);
        let is_hole = |u: usize, v: usize| (4..=7).contains(&u) && (3..=5).contains(&v);
        let known: Vec<bool> = (0..w * h).map(|i| !is_hole(i % w, i / w)).collect();
        let depth = |u: usize, v: usize| {
            if (3..=5).contains(&v) && u < 4 {
                near
            } else if (3..=5).contains(&v) && u > 7 {
                far
            } else {
                3.0
            }
        };
        warp_of(labelled, depth, &known, w, h)
    }

    #[test]
    fn early_iterations_keep_background_reads_along_columns() {
        // Up from every hole of the block to row 2 (depth 3, above the threshold of 2.5): kept
        // at the first iteration, each pixel the colour of its column's row 2.
        let warp = block_scene_at(1.0, 4.0);
        let holes = disocclusions(&warp);
        let out = run(&to_nearest_known(Direction::Up), &warp, &zero_prior(&warp), 3);
        assert_eq!(out.filled_per_iteration, [holes.len(), 0, 0]);
        for &(u, v) in &holes {
            assert_eq!(out.image.get(u, v), warp.image.get(u, 2), "({u}, {v})");
        }
    }

    #[test]
    fn the_last_iteration_refuses_reads_far_in_front_of_the_background() {
        // Foreground at 1, background at 20: the threshold is 10.5, and a read of depth 1 is
        // more than FOREGROUND_DEPTH_RATIO times nearer.
        let warp = block_scene_at(1.0, 20.0);
        let holes = disocclusions(&warp);
        let fill = fill_of(&warp);
        for iterations in [1, 3] {
            let out = run(&to_nearest_known(Direction::Left), &warp, &zero_prior(&warp), iterations);
            assert_eq!(out.image, fill, "P = {iterations}: the foreground reads take the fill value");
            assert_eq!((out.fell_back, out.foreground_reads, out.walked), (holes.len(), holes.len(), 0));
            for &(u, v) in &holes {
                assert_eq!(out.vectors.get(u, v), [8.0 - u as f32, 0.0], "the vector fill copied along");
            }
            // Upwards reads depth 3: in front of the threshold, so rejected by the early
            // iterations, but not 4 times nearer, so the last keeps it as the reference does.
            let out = run(&to_nearest_known(Direction::Up), &warp, &zero_prior(&warp), iterations);
            assert_eq!((out.fell_back, out.foreground_reads), (0, 0), "P = {iterations}");
            for &(u, v) in &holes {
                assert_eq!(out.image.get(u, v), labelled(u, 2), "P = {iterations} at ({u}, {v})");
            }
        }
        // The bound itself: background at 7 puts the threshold at 4 = 4 x the read, which is kept;
        // a little further and it is refused.
        for (far, refused) in [(7.0, 0), (7.01, holes.len())] {
            let warp = block_scene_at(1.0, far);
            let out = run(&to_nearest_known(Direction::Left), &warp, &zero_prior(&warp), 1);
            assert_eq!(out.foreground_reads, refused, "background at {far}");
            let want = if refused == 0 { labelled(3, 4) } else { labelled(8, 4) };
            assert_eq!(out.image.get(5, 4), want, "background at {far}");
        }
    }

    #[test]
    fn degenerate_vectors_take_the_fill_value() {
        let warp = block_scene();
        let holes = disocclusions(&warp);
        assert_eq!(holes.len(), 12);
        let fill = fill_of(&warp);
        for (u, v) in holes.iter().copied() {
            assert_eq!(fill.get(u, v), labelled(8, v), "fill copies the right neighbour");
        }
        for iterations in [1, 2, 3] {
            for vector in [[f32::NAN, 0.0], [0.0, f32::NAN], [f32::INFINITY, 0.0], [f32::NEG_INFINITY, 1.0], [0.0, 0.0]]
            {
                let out = run(&constant(vector), &warp, &zero_prior(&warp), iterations);
                assert_all_finite(&out.image);
                assert_eq!(out.image, fill, "{vector:?}, P = {iterations}");
                assert_eq!(out.fell_back, holes.len());
                assert_eq!(out.filled_per_iteration[iterations - 1], holes.len());
                // The vectors say where `fill` copied from.
                for &(u, v) in &holes {
                    assert_eq!(out.vectors.get(u, v), [8.0 - u as f32, 0.0]);
                }
            }
            // Huge vectors read nothing, so they walk: towards the background side that is the
            // pixel `fill` copies (depth 5 passes the threshold, but only a read can pass it).
            let out = run(&constant([1e6, 0.0]), &warp, &zero_prior(&warp), iterations);
            assert_eq!(out.image, fill, "P = {iterations}");
            assert_eq!((out.walked, out.fell_back), (holes.len(), 0));
            assert_eq!(out.filled_per_iteration[iterations - 1], holes.len());
            // Towards the foreground, the walk reads the foreground: the vector's direction rules.
            let out = run(&constant([-1e6, 0.0]), &warp, &zero_prior(&warp), iterations);
            for &(u, v) in &holes {
                assert_eq!(out.image.get(u, v), labelled(3, v));
                assert_eq!(out.vectors.get(u, v), [3.0 - u as f32, 0.0]);
            }
            for vector in [[1e6, 1e6], [f32::MAX, -f32::MAX], [-1e-30, 1e-30], [f32::MIN_POSITIVE, 0.0]] {
                let out = run(&constant(vector), &warp, &zero_prior(&warp), iterations);
                assert_all_finite(&out.image);
                assert!(out.vectors.as_flat().iter().all(|x| x.is_finite()));
                assert_eq!(out.fell_back, 0, "{vector:?}: every hole sees a known pixel within 100 px");
            }
        }
    }

    #[test]
    fn walk_takes_the_smallest_magnitude_that_reads_a_known_pixel() {
        // 120x5: row 2 is a hole from column 1 to 110 (known: column 0 and 111..). Wider than
        // tall, so a bounds check on the wrong axis would fail here.
        let (w, h) = (120, 5);
        let known: Vec<bool> = (0..w * h).map(|i| !(i / w == 2 && (1..=110).contains(&(i % w)))).collect();
        let warp = warp_of(labelled, |_, _| 2.0, &known, w, h);
        assert_eq!(warp.holes.count(PixelClass::Disocclusion), 110);
        let vectors = |u: usize, _| match u {
            // Target (22, 2) is a hole: walk right to column 111 (magnitude 91).
            20 => [2.0, 0.0],
            // Target between two holes: walk to column 111 (magnitude 61).
            50 => [0.5, 0.0],
            // Column 111 is 108 away: beyond 100, so `fill`.
            3 => [1.0, 0.0],
            // Left: (1, 2) is a hole, (0, 2) known at magnitude 2.
            2 => [-0.5, 0.0],
            // Reads its target directly: the bilinear mix of (0, 2) and its hole neighbour is (0, 2).
            1 => [-0.75, 0.0],
            // Straight up: row 1 is known.
            60 => [0.0, -7.0],
            _ => [0.0, 0.0],
        };
        let out = run(&per_pixel(vectors), &warp, &zero_prior(&warp), 1);
        let fill = fill_of(&warp);
        let o = |u, v| warp.image.get(u, v);
        assert_eq!((out.image.get(20, 2), out.vectors.get(20, 2)), (o(111, 2), [91.0, 0.0]));
        assert_eq!((out.image.get(50, 2), out.vectors.get(50, 2)), (o(111, 2), [61.0, 0.0]));
        assert_eq!(out.image.get(3, 2), fill.get(3, 2));
        assert_eq!((out.image.get(2, 2), out.vectors.get(2, 2)), (o(0, 2), [-2.0, 0.0]));
        assert_eq!((out.image.get(1, 2), out.vectors.get(1, 2)), (o(0, 2), [-0.75, 0.0]));
        assert_eq!((out.image.get(60, 2), out.vectors.get(60, 2)), (o(60, 1), [0.0, -1.0]));
        // Walked: 20, 50, 2, 60 and every zero vector falls back.
        assert_eq!(out.walked, 4);
        assert_eq!(out.fell_back, 110 - 5);

        // A diagonal walk lands between pixels: block of holes at columns 2..=6, rows 2..=4.
        let (w, h) = (9, 7);
        let known: Vec<bool> =
            (0..w * h).map(|i| !((2..=6).contains(&(i % w)) && (2..=4).contains(&(i / w)))).collect();
        let warp = warp_of(labelled, |_, _| 2.0, &known, w, h);
        // From (4, 3) along (0.6, 0.8): the target (4.3, 3.4) and magnitude 1 (4.6, 3.8) have only
        // hole corners; magnitude 2 (5.2, 4.6) has the known corners (5, 5) and (6, 5).
        let out = run(
            &per_pixel(|u, v| if (u, v) == (4, 3) { [0.3, 0.4] } else { [0.0, 0.0] }),
            &warp,
            &zero_prior(&warp),
            1,
        );
        let [a, b] = out.vectors.get(4, 3);
        assert!((a - 1.2).abs() < 1e-6 && (b - 1.6).abs() < 1e-6, "{a}, {b}");
        let want = sample_known(&warp.image, &known, 4.0 + a, 3.0 + b).unwrap();
        assert_eq!(out.image.get(4, 3), want);
        let mix = |c: usize| (0.8 * labelled(5, 5)[c] + 0.2 * labelled(6, 5)[c]) / 1.0;
        assert!((0..3).all(|c| (want[c] - mix(c)).abs() < 1e-6), "{want:?}");
        assert_eq!(out.walked, 1);
    }

    /// 8x5, row 2 is a hole from column 2 to 5; uniform depth (every threshold equals it).
    fn row_scene() -> Warp {
        let (w, h) = (8, 5);
        let known: Vec<bool> = (0..w * h).map(|i| !(i / w == 2 && (2..=5).contains(&(i % w)))).collect();
        warp_of(labelled, |_, _| 4.0, &known, w, h)
    }

    #[test]
    fn vectors_compose_across_iterations() {
        let warp = row_scene();
        let right = labelled(6, 2);
        // Every hole reads one pixel to the right: one pixel is filled per iteration, from the
        // right, each reading the one filled before it.
        let out = run(&constant([1.0, 0.0]), &warp, &zero_prior(&warp), 3);
        assert_eq!(out.filled_per_iteration, [1, 1, 2]);
        // (3, 2) reads (4, 2) filled in iteration 2; (2, 2) reads the hole (3, 2): walks to (4, 2).
        assert_eq!((out.walked, out.fell_back), (1, 0));
        for u in 2..=5 {
            assert_eq!(out.image.get(u, 2), right, "column {u}");
            assert_eq!(out.composed_vectors.get(u, 2), [6.0 - u as f32, 0.0], "column {u}");
            assert_eq!(out.vectors.get(u, 2), [if u == 2 { 2.0 } else { 1.0 }, 0.0], "column {u}");
        }
        let out = run(&constant([1.0, 0.0]), &warp, &zero_prior(&warp), 2);
        assert_eq!(out.filled_per_iteration, [1, 3]);
        assert!((2..=5).all(|u| out.image.get(u, 2) == right));
        // P = 1: all walk over the holes to column 6, except (5, 2) which reads it directly.
        let out = run(&constant([1.0, 0.0]), &warp, &zero_prior(&warp), 1);
        assert_eq!((out.filled_per_iteration.as_slice(), out.walked), (&[4][..], 3));
        for u in 2..=5 {
            assert_eq!(out.image.get(u, 2), right, "column {u}");
            assert_eq!(out.vectors.get(u, 2), [6.0 - u as f32, 0.0], "column {u}");
        }
    }

    #[test]
    fn the_next_prediction_sees_the_kept_vectors_and_depths() {
        let warp = row_scene();
        let w = warp.image.width();
        let mut prior = zero_prior(&warp);
        prior.set(1, 1, [0.25, -0.5]);
        prior.set(6, 3, [-1.0, 0.0]);
        let predictor = Recording::new(constant([1.0, 0.0]));
        run(&predictor, &warp, &prior, 3);
        let calls = predictor.calls();
        assert_eq!(calls.len(), 3);
        assert_eq!(calls[0].prior, prior);
        assert_eq!(calls[0].depth, warp.depth);
        assert_eq!(calls[0].holes, warp.holes.disocclusions());
        // Iteration 1 kept (5, 2): its vector joins the prior, its depth the depth map.
        let mut want_prior = prior.clone();
        want_prior.set(5, 2, [1.0, 0.0]);
        let mut want_depth = warp.depth.clone();
        want_depth.set(5, 2, [4.0]);
        let mut want_holes = warp.holes.disocclusions();
        want_holes[2 * w + 5] = false;
        assert_eq!((&calls[1].prior, &calls[1].depth, &calls[1].holes), (&want_prior, &want_depth, &want_holes));
        // Iteration 2 kept (4, 2).
        want_prior.set(4, 2, [1.0, 0.0]);
        want_depth.set(4, 2, [4.0]);
        want_holes[2 * w + 4] = false;
        assert_eq!((&calls[2].prior, &calls[2].depth, &calls[2].holes), (&want_prior, &want_depth, &want_holes));
    }

    #[test]
    fn a_frame_without_disocclusions_never_calls_the_predictor() {
        let (w, h) = (7, 5);
        let never = FnPredictor(|_: &VectorField, _: &DepthMap, _: &[bool]| -> VectorField {
            panic!("predict called without holes")
        });
        // No hole at all: the warp itself.
        let full = warp_of(labelled, |_, _| 2.0, &vec![true; w * h], w, h);
        let out = run(&never, &full, &zero_prior(&full), 3);
        assert_eq!(out.image, full.image);
        assert_eq!((out.filled_per_iteration.as_slice(), out.predictions), (&[0, 0, 0][..], 0));
        // New regions only (the last column): the warp with the common new-region rule.
        let known: Vec<bool> = (0..w * h).map(|i| i % w != w - 1).collect();
        let border = warp_of(labelled, |_, _| 2.0, &known, w, h);
        assert_eq!(border.holes.count(PixelClass::NewRegion), h);
        let out = run(&never, &border, &zero_prior(&border), 3);
        let mut want = border.image.clone();
        fill_new_regions(&mut want, &border.holes);
        assert_eq!(out.image, want);
        assert!((0..h).all(|v| out.image.get(w - 1, v) == labelled(w - 2, v)));
        assert_eq!(out.vectors, zero_prior(&border));
    }

    #[test]
    fn all_hole_frames_give_finite_images() {
        let (w, h) = (7, 5);
        // As the warper classifies it: all new region, nothing to predict, nothing to copy.
        let empty = warp_of(labelled, |_, _| 2.0, &vec![false; w * h], w, h);
        let never = FnPredictor(|_: &VectorField, _: &DepthMap, _: &[bool]| -> VectorField { panic!("called") });
        let out = run(&never, &empty, &zero_prior(&empty), 3);
        assert_eq!(out.image, empty.image);
        // Declared all disocclusion: predicted, but nothing is ever readable; stays as warped.
        let holes = HoleMask::uniform(w, h, PixelClass::Disocclusion);
        let all = Warp { holes, ..empty };
        for vector in [[1.0, 0.0], [0.0, 0.0], [f32::NAN, 2.0], [1e6, -1e6]] {
            for iterations in [1, 3] {
                let predictor = Recording::new(constant(vector));
                let out = run(&predictor, &all, &zero_prior(&all), iterations);
                assert_all_finite(&out.image);
                assert_eq!(out.image, all.image);
                assert_eq!(out.fell_back, w * h);
                assert_eq!(predictor.calls().len(), iterations);
            }
        }
    }

    #[test]
    fn odd_sizes_random_vectors_are_deterministic_and_finite() {
        let (w, h) = (13, 7);
        let is_hole = |u: usize, v: usize| ((3..=8).contains(&u) && (2..=4).contains(&v)) || (u, v) == (10, 5);
        let known: Vec<bool> = (0..w * h).map(|i| !is_hole(i % w, i / w)).collect();
        let depth = |u: usize, v: usize| if u < 6 { 1.0 + v as f32 * 0.1 } else { 6.0 + u as f32 * 0.3 };
        let warp = warp_of(labelled, depth, &known, w, h);
        let count = warp.holes.count(PixelClass::Disocclusion);
        assert_eq!(count, 19);
        // Pseudo-random vectors in +-8 px that change with the iteration (through the depth seen).
        let predictor = FnPredictor(|_: &VectorField, depth: &DepthMap, holes: &[bool]| {
            let salt = depth.pixels().iter().filter(|&&[z]| z > 0.0).count();
            on_holes(depth, holes, |u, v| {
                let hash = ((u * 73 + v * 151 + salt * 29) as u32).wrapping_mul(2_654_435_761);
                if (u, v) == (5, 3) || hash % 17 == 3 {
                    return [f32::NAN, 1.0];
                }
                [((hash >> 8) % 1601) as f32 / 100.0 - 8.0, ((hash >> 20) % 1601) as f32 / 100.0 - 8.0]
            })
        });
        for iterations in [1, 2, 3] {
            let on = |threads| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                pool.install(|| run(&predictor, &warp, &zero_prior(&warp), iterations))
            };
            let (one, three) = (on(1), on(3));
            assert_eq!(one.image, three.image);
            assert_eq!(one.vectors, three.vectors);
            assert_eq!(one.filled_per_iteration, three.filled_per_iteration);
            assert_all_finite(&one.image);
            assert_eq!(one.filled_per_iteration.iter().sum::<usize>(), count);
            assert!(one.fell_back >= 1, "the NaN vectors fall back");
            for v in 0..h {
                for u in 0..w {
                    if known[v * w + u] {
                        assert_eq!(one.image.get(u, v), warp.image.get(u, v));
                    } else {
                        // Every read mixes known colours: blue channel 0.5 throughout.
                        assert!((one.image.get(u, v)[2] - 0.5).abs() < 1e-6, "({u}, {v})");
                    }
                }
            }
        }
    }

    /// 14x8: a sliver of disocclusions 2 pixels wide (columns 2-3, rows 1-5) between a
    /// foreground column (1, depth 1) and background (depth 5), and a 5x5 block of them (columns
    /// 7-11, rows 1-5) with background around it.
    fn sliver_and_block() -> Warp {
        let hole = |u: usize, v: usize| (1..=5).contains(&v) && ((2..=3).contains(&u) || (7..=11).contains(&u));
        let known: Vec<bool> = (0..8).flat_map(|v| (0..14).map(move |u| !hole(u, v))).collect();
        warp_of(labelled, |u, _| if u <= 1 { 1.0 } else { 5.0 }, &known, 14, 8)
    }

    #[test]
    fn thin_runs_copy_their_background_end_before_the_passes() {
        let warp = sliver_and_block();
        let sliver: Vec<Pixel> = (1..=5).flat_map(|v| [(2, v), (3, v)]).collect();
        for thin_run in [2, 3] {
            // Vectors onto the foreground column: the passes would copy it into the sliver.
            let predictor = Recording::new(to_nearest_known(Direction::Left));
            let prior = ScaledPrior::full_size(zero_prior(&warp));
            let out =
                infill_iteratively(&predictor, &warp.image, &warp.depth, &warp.holes, &prior, 3, thin_only(thin_run))
                    .unwrap();
            assert_eq!(out.thin_runs, sliver.len(), "thin_run {thin_run}");
            assert_eq!(out.filled_per_iteration.iter().sum::<usize>(), 25, "the block is the passes'");
            for &(u, v) in &sliver {
                assert_eq!(out.image.get(u, v), labelled(4, v), "({u}, {v}) copies the background end");
                assert_eq!(out.vectors.get(u, v), [4.0 - u as f32, 0.0]);
                assert_eq!(out.composed_vectors.get(u, v), [4.0 - u as f32, 0.0]);
            }
            // The passes see the sliver known, at the depth it copied, with its vector as prior.
            let first = &predictor.calls()[0];
            for &(u, v) in &sliver {
                assert!(!first.holes[v * 14 + u]);
                assert_eq!(first.depth.get(u, v), [5.0]);
                assert_eq!(first.prior.get(u, v), [4.0 - u as f32, 0.0]);
            }
            assert!(first.holes[3 * 14 + 9], "the block's centre is still a hole");
        }
        // A run of 1 is shorter than the sliver: the passes fill it, from the foreground.
        let predictor = to_nearest_known(Direction::Left);
        let out = run(&predictor, &warp, &zero_prior(&warp), 3);
        assert_eq!(out.thin_runs, 0);
        assert_eq!(out.image.get(2, 3), labelled(1, 3));
    }

    #[test]
    fn a_frame_of_thin_runs_alone_never_calls_the_network() {
        let warp = sliver_and_block();
        let known: Vec<bool> =
            (0..8).flat_map(|v| (0..14).map(move |u| !((1..=5).contains(&v) && (2..=3).contains(&u)))).collect();
        let only_sliver = warp_of(labelled, |u, _| if u <= 1 { 1.0 } else { 5.0 }, &known, 14, 8);
        assert!(warp.holes.disocclusions().iter().filter(|&&h| h).count() > 10);
        let predictor = Recording::new(constant([1.0, 0.0]));
        let prior = ScaledPrior::full_size(zero_prior(&only_sliver));
        let out = infill_iteratively(
            &predictor,
            &only_sliver.image,
            &only_sliver.depth,
            &only_sliver.holes,
            &prior,
            3,
            thin_only(3),
        )
        .unwrap();
        assert_eq!((out.thin_runs, out.predictions, predictor.calls().len()), (10, 0, 0));
        assert_eq!(out.filled_per_iteration, [0, 0, 0]);
    }

    #[test]
    fn the_far_blur_runs_after_the_passes_on_the_disocclusions_alone() {
        let warp = sliver_and_block();
        let prior = ScaledPrior::full_size(zero_prior(&warp));
        let predictor = to_nearest_known(Direction::Right);
        let infill = |far_blur| {
            let rules = InfillRules { thin_run: 3, far_blur };
            infill_iteratively(&predictor, &warp.image, &warp.depth, &warp.holes, &prior, 3, rules).unwrap()
        };
        let (sharp, blurred) = (infill(0.0), infill(0.5));
        // The same passes, then the blur of every disocclusion pixel over the others, each at its
        // distance to the nearest known pixel along its row or column.
        let disocclusions = warp.holes.indices_of(PixelClass::Disocclusion);
        let w = warp.image.width();
        let known = |u: usize, v: usize| warp.holes.is_known(u, v);
        let distances: Vec<f32> = disocclusions
            .iter()
            .map(|&i| {
                let (u, v) = (i % w, i / w);
                let along_row = (0..w).filter(|&x| known(x, v)).map(|x| x.abs_diff(u));
                let along_column = (0..warp.image.height()).filter(|&y| known(u, y)).map(|y| y.abs_diff(v));
                along_row.chain(along_column).min().map_or(f32::INFINITY, |d| d as f32)
            })
            .collect();
        let mut expected = sharp.image.clone();
        blur_far_pixels(&mut expected, &disocclusions, &distances, 0.5);
        assert_eq!(blurred.image.pixels(), expected.pixels());
        assert_eq!((blurred.vectors.pixels(), blurred.thin_runs), (sharp.vectors.pixels(), sharp.thin_runs));
        // A pixel of the block 2 pixels from the known frame took a mean of its neighbours (rows
        // copied from the right, the colour's green grows with the row).
        assert!(blurred.image.get(9, 2)[1] > sharp.image.get(9, 2)[1] + 1e-3);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let warp = row_scene();
        let prior = ScaledPrior::full_size(zero_prior(&warp));
        let ok = constant([1.0, 0.0]);
        let err =
            |result: Result<IterativeInfill, InfillError>| matches!(result, Err(InfillError::SizeMismatch { .. }));
        let no_iterations =
            infill_iteratively(&ok, &warp.image, &warp.depth, &warp.holes, &prior, 0, InfillRules::NONE);
        assert!(matches!(no_iterations, Err(InfillError::NoIterations)));
        assert!(err(infill_iteratively(
            &ok,
            &warp.image,
            &warp.depth,
            &warp.holes,
            &ScaledPrior::zeros(3, 3, 1),
            3,
            InfillRules::NONE
        )));
        assert!(err(infill_iteratively(
            &ok,
            &warp.image,
            &DepthMap::zeros(8, 4),
            &warp.holes,
            &prior,
            3,
            InfillRules::NONE
        )));
        // A hole mask wrong in either side alone, the other right.
        let (w, h) = (warp.image.width(), warp.image.height());
        for (mw, mh) in [(w + 1, h), (w, h + 1)] {
            let mask = HoleMask::classify(mw, mh, &vec![true; mw * mh]);
            let result = infill_iteratively(&ok, &warp.image, &warp.depth, &mask, &prior, 3, InfillRules::NONE);
            assert!(
                matches!(result, Err(InfillError::SizeMismatch { what: "the hole mask", .. })),
                "a {mw}x{mh} mask for a {w}x{h} frame: {result:?}"
            );
        }
        let wrong_size = FnPredictor(|_: &VectorField, _: &DepthMap, _: &[bool]| VectorField::zeros(2, 2));
        assert!(err(infill_iteratively(
            &wrong_size,
            &warp.image,
            &warp.depth,
            &warp.holes,
            &prior,
            3,
            InfillRules::NONE
        )));
        struct Failing;
        impl VectorPredictor for Failing {
            fn predict(&self, _: &VectorField, _: &DepthMap, _: &[bool]) -> Result<VectorField, InfillError> {
                Err(candle_core::Error::Msg("no model".into()).into())
            }
        }
        let result = infill_iteratively(&Failing, &warp.image, &warp.depth, &warp.holes, &prior, 3, InfillRules::NONE);
        assert!(matches!(&result, Err(InfillError::Network(e)) if e.to_string().contains("no model")), "{result:?}");
    }
}
