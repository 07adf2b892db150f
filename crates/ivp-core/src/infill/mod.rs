//! Infillers: every method that turns a warped frame with holes into a full frame, behind one trait.
//!
//! Every method infills the disocclusions its own way; the new regions get one common rule
//! ([`fill_new_regions`]) so that whole-frame metrics compare like with like (ALGORITHMS.md §4.1).
//!
//! Classical methods: `copy` (the last rendered frame), `warp` (the warped frame, disocclusions
//! black), `fill` (each disocclusion copies its background neighbour), `oracle` (fictitious
//! vectors measured on the ground truth, an upper bound for vector prediction) and `telea`
//! (OpenCV's Telea inpainting of the disocclusions, radius 5, in `telea.rs`).
//!
//! Layer: imports `geometry` and `prior`, never `nn` (the network reaches infilling through the
//! [`VectorPredictor`] trait, implemented in `inference`).

pub mod classical;
pub mod far_blur;
pub mod iterative;
pub mod rules;
pub mod telea;

pub use classical::{classical_infiller, BackgroundFill, CopyLast, Oracle, WarpOnly, CLASSICAL_METHODS};
pub use far_blur::{blur_far_pixels, FAR_BLUR};
pub use iterative::{
    infill_iteratively, InfillRules, IterativeInfill, VectorPredictor, DEFAULT_ITERATIONS, MAX_WALK_MAGNITUDE,
};
pub use rules::{
    background_source, fill_disocclusions_background, fill_new_regions, new_region_source, thin_run_source, THIN_RUN,
};
pub use telea::{inpaint_telea, Telea, TELEA_RADIUS};

use std::time::{Duration, Instant};

use crate::geometry::{FrameView, Intrinsics, RgbImage, VectorField, Warp, WorldToCamera};
use crate::prior::{target_prior, TargetPrior};

/// Everything a method may use to predict frame `t = n + 1`.
#[derive(Clone, Copy, Debug)]
pub struct InfillContext<'a> {
    pub intrinsics: &'a Intrinsics,
    /// Frame `n`, the last rendered frame.
    pub last: FrameView<'a>,
    /// Frame `n - 2`, for the temporal prior; `None` at the start of a sequence.
    pub before_last: Option<FrameView<'a>>,
    /// The pose of the frame to predict (known from the head tracker).
    pub target_pose: &'a WorldToCamera,
    /// Frame `n` warped into the target view (computed once, shared by all methods).
    pub warped: &'a Warp,
    /// The target frame itself; only methods that say they use ground truth may read it.
    pub ground_truth: Option<&'a RgbImage>,
}

impl InfillContext<'_> {
    /// The temporal prior of the target (ALGORITHMS.md §6.2), from frames `n - 2` and `n`; `None` at the
    /// start of a sequence, where there is no frame `n - 2`.
    pub fn temporal_prior(&self) -> Option<TargetPrior> {
        let before_last = self.before_last.as_ref()?;
        Some(target_prior(before_last, &self.last, self.target_pose, self.intrinsics, &self.warped.holes.known()))
    }
}

/// The prediction of one frame and where the method spent its time.
#[derive(Clone, Debug)]
pub struct Infilled {
    pub image: RgbImage,
    /// Time by stage (`"prior"`, `"network"`, `"infill"`), in the order the stages ran.
    pub stages: Vec<(&'static str, Duration)>,
    /// For methods that fill by vectors (`oracle`, a network's vector variants): per disocclusion
    /// pixel, the vector it was filled with (zero elsewhere), for reports to draw. `None` for the
    /// others.
    pub vectors: Option<VectorField>,
}

#[derive(Debug, thiserror::Error)]
pub enum InfillError {
    #[error("method `{0}` needs the ground-truth target frame, which this context does not have")]
    NeedsGroundTruth(&'static str),
    /// An input does not have the warped frame's size.
    #[error("{what} is {}x{} but the warped frame is {}x{}", found.0, found.1, expected.0, expected.1)]
    SizeMismatch { what: &'static str, found: (usize, usize), expected: (usize, usize) },
    #[error("iterative infilling needs at least one iteration")]
    NoIterations,
    #[error("the intensity variant predicts colours, not vectors")]
    NotVectors,
    /// The network's forward pass failed.
    #[error("network: {0}")]
    Network(#[from] candle_core::Error),
    /// Broken weights or inputs must not pass for a prediction (the iterative infilling would
    /// silently fall back to `fill`).
    #[error(
        "network: {count} of {total} hole pixels got non-finite vectors (NaN or infinite): the model's weights or \
         inputs are broken"
    )]
    NonFiniteVectors { count: usize, total: usize },
}

/// A method that predicts a frame from its warped version.
pub trait Infiller: Send + Sync {
    /// The name used on the command line and in tables.
    fn name(&self) -> &str;

    /// True for methods that read the target frame: every output must say so.
    fn uses_ground_truth(&self) -> bool {
        false
    }

    /// False for methods that ignore [`InfillContext::warped`]: their time excludes the warp.
    fn uses_warp(&self) -> bool {
        true
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError>;
}

/// Runs `f` and measures how long it took.
pub(crate) fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let start = Instant::now();
    let out = f();
    (out, start.elapsed())
}

pub(crate) fn infilled_in_one_stage(image: RgbImage, elapsed: Duration) -> Infilled {
    Infilled { image, stages: vec![("infill", elapsed)], vectors: None }
}
