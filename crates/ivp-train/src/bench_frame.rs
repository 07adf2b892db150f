//! `ivp bench frame`: one frame end to end on a generated clip (warp, holes, prior, network,
//! infill), split by stage, with the hole fraction, the tiles run and the frame's D-MSE beside
//! `fill`'s, so that every time is printed with its error.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use ivp_core::geometry::FrameView;
use ivp_core::inference::{Coverage, ModelInfiller, Scale};
use ivp_core::infill::{classical_infiller, InfillContext};
use ivp_core::metrics::score_frame;
use ivp_core::nn::model::{IvpNet, ModelConfig, Variant};
use ivp_core::{relative_pose, warp_forward};
use ivp_data::{render_clip, SceneParams};
use serde::Serialize;

use ivp_core::nn::ops::profile;

use crate::bench::{operator_breakdown, OperatorTimes};
use crate::checkpoint::load_model;

/// What `ivp bench frame` times.
#[derive(Clone, Debug)]
pub struct FrameCase {
    pub height: usize,
    pub width: usize,
    /// A trained model; without it, a network of `width_mult` with seeded (untrained) weights.
    pub model: Option<PathBuf>,
    pub width_mult: f64,
    /// The depth head's width multiplier of the untrained network.
    pub depth_head_mult: f64,
    pub iterations: usize,
    pub coverage: Coverage,
    /// The scale the model runs at.
    pub scale: Scale,
    /// Timed runs, after one untimed warm-up run.
    pub runs: usize,
    /// Seed of the generated scene (and of the untrained weights).
    pub seed: u64,
    /// Also report the network's time by operator.
    pub profile: bool,
}

/// Milliseconds of one stage over the timed runs.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct StageTime {
    pub median_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub case: &'static str,
    pub height: usize,
    pub width: usize,
    pub width_mult: f64,
    pub depth_head_mult: f64,
    pub trained: bool,
    pub iterations: usize,
    pub coverage: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_core: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_margin: Option<usize>,
    /// The factor the frame was shrunk by before the network saw it.
    pub scale: usize,
    pub runs: usize,
    pub threads: usize,
    /// Disocclusions as a fraction of the frame.
    pub hole_fraction: f64,
    /// Tiles the network ran on over the iterations of one frame (0 when dense).
    pub tiles: usize,
    /// By stage: `warp`, `holes`, `prior`, `network`, `infill`, and `total`.
    pub stages: BTreeMap<&'static str, StageTime>,
    /// D-MSE of the frame (8-bit), and of `fill` on the same warp.
    pub d_mse: Option<f64>,
    pub d_mse_fill: Option<f64>,
    /// Milliseconds per run of the network stage by operator (`--profile`); `other` is the rest
    /// of the stage (inputs, outputs, candle's own operators).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub network_profile: Option<OperatorTimes>,
}

/// Frame `n - 2`, `n` and the target `t = n + 1` of the generated clip.
const FRAMES: usize = 4;
const TARGET: usize = 3;

pub fn bench_frame(case: &FrameCase) -> Result<FrameReport> {
    ensure!(case.runs > 0 && case.iterations > 0, "--runs and --iterations must be at least 1");
    let net = match &case.model {
        Some(path) => load_model(path)?.0,
        None => {
            let config = ModelConfig::new(Variant::Full, case.width_mult).with_depth_head_mult(case.depth_head_mult);
            IvpNet::seeded(config, case.seed).context("building the network")?.0.detached()
        }
    };
    ensure!(net.config().variant.predicts_vectors(), "ivp bench frame times the vector variants only");
    let (width_mult, depth_head_mult) = (net.config().width_mult, net.config().depth_head_mult);
    let model = ModelInfiller::new("ivp", net, case.iterations).with_coverage(case.coverage).with_scale(case.scale);
    let params = SceneParams { width: case.width, height: case.height, frames: FRAMES, ..Default::default() };
    let clip = render_clip(case.seed, &params);
    let view =
        |i: usize| FrameView { image: &clip.frames[i].image, depth: &clip.frames[i].depth, pose: &clip.poses[i] };
    let (last, target) = (TARGET - 1, TARGET);
    let to_target = relative_pose(&clip.poses[last], &clip.poses[target]);

    let mut times: BTreeMap<&'static str, Vec<Duration>> = BTreeMap::new();
    let mut outcome = None;
    for run in 0..=case.runs {
        let started = Instant::now();
        let warp = warp_forward(&clip.frames[last].image, &clip.frames[last].depth, &clip.intrinsics, &to_target);
        let warp_time = started.elapsed();
        let started = Instant::now();
        let disocclusions = warp.holes.disocclusions();
        let holes_time = started.elapsed();
        let ctx = InfillContext {
            intrinsics: &clip.intrinsics,
            last: view(last),
            before_last: Some(view(TARGET - 3)),
            target_pose: &clip.poses[target],
            warped: &warp,
            ground_truth: None,
        };
        if run == 1 {
            profile::set_enabled(case.profile);
            profile::take();
        }
        let prediction = model.predict(&ctx)?;
        if run == 0 {
            continue; // warm-up: first touches of the feature maps' memory
        }
        let mut stages = vec![("warp", warp_time), ("holes", holes_time)];
        stages.extend(prediction.stages.iter().copied());
        let total: Duration = stages.iter().map(|(_, t)| *t).sum();
        for (name, t) in stages.into_iter().chain([("total", total)]) {
            times.entry(name).or_default().push(t);
        }
        if outcome.is_none() {
            let fill = classical_infiller("fill").expect("a classical method").infill(&ctx)?.image;
            let truth = &clip.frames[target].image;
            let score =
                |image: &ivp_core::RgbImage| score_frame(&image.quantized_to_8bit(), truth, &disocclusions).d_mse;
            let hole_fraction = disocclusions.iter().filter(|&&d| d).count() as f64 / disocclusions.len() as f64;
            outcome = Some((hole_fraction, prediction.tiles, score(&prediction.image), score(&fill)));
        }
    }
    profile::set_enabled(false);
    let operators = profile::take();
    let network_profile = case.profile.then(|| operator_breakdown(&operators, &times["network"]));
    let (hole_fraction, tiles, d_mse, d_mse_fill) = outcome.expect("at least one timed run");
    let (tile_core, tile_margin) = match case.coverage {
        Coverage::Sparse(shape) => (Some(shape.core), Some(shape.margin)),
        Coverage::Dense => (None, None),
    };
    Ok(FrameReport {
        case: "frame",
        height: case.height,
        width: case.width,
        width_mult,
        depth_head_mult,
        trained: case.model.is_some(),
        iterations: case.iterations,
        coverage: if tile_core.is_some() { "sparse" } else { "dense" },
        tile_core,
        tile_margin,
        scale: case.scale.factor(case.height),
        runs: case.runs,
        threads: rayon::current_num_threads(),
        hole_fraction,
        tiles,
        stages: times.into_iter().map(|(name, t)| (name, stage_time(t))).collect(),
        d_mse,
        d_mse_fill,
        network_profile,
    })
}

fn stage_time(mut times: Vec<Duration>) -> StageTime {
    times.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    StageTime { median_ms: ms(times[times.len() / 2]), min_ms: ms(times[0]), max_ms: ms(times[times.len() - 1]) }
}
