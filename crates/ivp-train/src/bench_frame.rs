//! `ivp bench frame`: one frame end to end (warp, holes, prior, network, infill), split by stage,
//! with the hole fraction, the tiles run, the pixels they read and the frame's D-MSE beside
//! `fill`'s, so that every time is printed with its error. The frame is generated, or each target
//! of a clip on disk (`--data CLIP --targets ...`): users judge the speed on their own frames.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use ivp_core::inference::{Coverage, ModelInfiller, PriorScale, Scale};
use ivp_core::infill::{classical_infiller, InfillContext, InfillRules};
use ivp_core::metrics::score_frame;
use ivp_core::nn::model::{IvpNet, ModelConfig, Variant};
use ivp_core::{relative_pose, warp_forward};
use ivp_data::samples::ClipFrames;
use ivp_data::{render_clip, Clip, SceneParams};
use serde::Serialize;

use ivp_core::nn::ops::profile;

use crate::bench::{operator_breakdown, OperatorTimes};
use crate::checkpoint::load_model;
use crate::eval::check_targets;
use crate::machine::Machine;

/// Where the frames come from.
#[derive(Clone, Debug)]
pub enum FrameSource {
    /// One generated frame of this size (the scene of `seed`).
    Generated { height: usize, width: usize, seed: u64 },
    /// Targets of a clip on disk, each predicted from frames `t - 3` and `t - 1` as `ivp eval` does.
    Clip { dir: PathBuf, targets: Vec<usize> },
}

/// What `ivp bench frame` times.
#[derive(Clone, Debug)]
pub struct FrameCase {
    pub frames: FrameSource,
    /// A trained model; without it, a network of `width_mult` with seeded (untrained) weights.
    pub model: Option<PathBuf>,
    pub width_mult: f64,
    /// The depth head's width multiplier of the untrained network.
    pub depth_head_mult: f64,
    pub iterations: usize,
    /// The rules around the passes (thin runs, far blur).
    pub rules: InfillRules,
    pub coverage: Coverage,
    /// The scale the model runs at.
    pub scale: Scale,
    /// The scale its temporal prior is measured at.
    pub prior_scale: PriorScale,
    /// Timed runs, after one untimed warm-up run.
    pub runs: usize,
    /// Seed of the untrained weights.
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
    /// The clip and target of a frame read from disk.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clip: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target: Option<usize>,
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
    /// The factor the frames were shrunk by before the temporal prior was measured on them.
    pub prior_scale: usize,
    pub runs: usize,
    pub threads: usize,
    /// The CPU the times were measured on.
    pub machine: Machine,
    /// Disocclusions as a fraction of the frame.
    pub hole_fraction: f64,
    /// Tiles the network ran on over the iterations of one frame (0 when dense).
    pub tiles: usize,
    /// Pixels of the frame the network saw (shrunk by `scale`) that it read over the iterations of
    /// one frame, as a fraction of that frame's pixels (3 = three dense passes).
    pub pixels_read_fraction: f64,
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

/// The frames of a clip's run: every target's report, and the end-to-end time over them.
#[derive(Clone, Debug, Serialize)]
pub struct ClipReport {
    pub case: &'static str,
    pub clip: String,
    /// The median, fastest and slowest of the frames' median `total` times.
    pub total_over_frames: StageTime,
    pub frames: Vec<FrameReport>,
}

/// Frame `n - 2`, `n` and the target `t = n + 1` of the generated clip.
const GENERATED_FRAMES: usize = 4;
const GENERATED_TARGET: usize = 3;

/// Times the generated frame of `case` (`FrameSource::Generated`).
pub fn bench_frame(case: &FrameCase) -> Result<FrameReport> {
    let FrameSource::Generated { height, width, seed } = case.frames else {
        anyhow::bail!("bench_frame times a generated frame: use bench_clip for a clip");
    };
    let model = model_of(case)?;
    let params = SceneParams { width, height, frames: GENERATED_FRAMES, ..Default::default() };
    let clip: ClipFrames = render_clip(seed, &params).into();
    time_target(case, &model, &clip, GENERATED_TARGET)
}

/// Times every target of the clip of `case` (`FrameSource::Clip`).
pub fn bench_clip(case: &FrameCase) -> Result<ClipReport> {
    let FrameSource::Clip { dir, targets } = &case.frames else {
        anyhow::bail!("bench_clip times the targets of a clip: use bench_frame for a generated frame");
    };
    ensure!(!targets.is_empty(), "--targets: give at least one target");
    let model = model_of(case)?;
    let clip = Clip::open(dir)?;
    check_targets(&clip, targets)?;
    let mut frames = Vec::with_capacity(targets.len());
    for &t in targets {
        // Only the frames a target reads: t - 3, t - 1 and t itself.
        let first = t - 3;
        let loaded = ClipFrames {
            frames: (first..=t).map(|i| clip.load_frame(i)).collect::<Result<_, _>>()?,
            poses: clip.poses()[first..=t].to_vec(),
            intrinsics: *clip.intrinsics(),
        };
        let mut report = time_target(case, &model, &loaded, 3)?;
        report.case = "clip";
        report.clip = Some(dir.display().to_string());
        report.target = Some(t);
        frames.push(report);
    }
    let totals: Vec<Duration> =
        frames.iter().map(|f| Duration::from_secs_f64(f.stages["total"].median_ms / 1e3)).collect();
    Ok(ClipReport { case: "clip", clip: dir.display().to_string(), total_over_frames: stage_time(totals), frames })
}

fn model_of(case: &FrameCase) -> Result<ModelInfiller> {
    ensure!(case.runs > 0 && case.iterations > 0, "--runs and --iterations must be at least 1");
    let net = match &case.model {
        Some(path) => load_model(path)?.0,
        None => {
            let config = ModelConfig::new(Variant::Full, case.width_mult).with_depth_head_mult(case.depth_head_mult);
            IvpNet::seeded(config, case.seed).context("building the network")?.0.detached()
        }
    };
    ensure!(net.config().variant.predicts_vectors(), "ivp bench frame times the vector variants only");
    Ok(ModelInfiller::new("ivp", net, case.iterations)
        .with_coverage(case.coverage)
        .with_scale(case.scale)
        .with_prior_scale(case.prior_scale)
        .with_rules(case.rules))
}

/// Target `target` of `clip` (frames `target - 3 ..= target` present) predicted `case.runs` times
/// after a warm-up run, by stage, as `ivp eval` predicts it.
fn time_target(case: &FrameCase, model: &ModelInfiller, clip: &ClipFrames, target: usize) -> Result<FrameReport> {
    let (width_mult, depth_head_mult) = (model.net().config().width_mult, model.net().config().depth_head_mult);
    let (width, height) = clip.size();
    let last = target - 1;
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
            last: clip.view(last),
            before_last: Some(clip.view(target - 3)),
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
            let factor = case.scale.factor(height);
            let seen = width.div_ceil(factor) * height.div_ceil(factor);
            let read = prediction.pixels_read as f64 / seen as f64;
            outcome = Some((hole_fraction, prediction.tiles, read, score(&prediction.image), score(&fill)));
        }
    }
    profile::set_enabled(false);
    let operators = profile::take();
    let network_profile = case.profile.then(|| operator_breakdown(&operators, &times["network"]));
    let (hole_fraction, tiles, pixels_read_fraction, d_mse, d_mse_fill) = outcome.expect("at least one timed run");
    let (tile_core, tile_margin) = match case.coverage {
        Coverage::Sparse(shape) => (Some(shape.core), Some(shape.margin)),
        Coverage::Dense => (None, None),
    };
    Ok(FrameReport {
        case: "frame",
        clip: None,
        target: None,
        height,
        width,
        width_mult,
        depth_head_mult,
        trained: case.model.is_some(),
        iterations: case.iterations,
        coverage: if tile_core.is_some() { "sparse" } else { "dense" },
        tile_core,
        tile_margin,
        scale: case.scale.factor(height),
        prior_scale: case.prior_scale.factor(case.scale.factor(height)),
        runs: case.runs,
        threads: rayon::current_num_threads(),
        machine: Machine::this(),
        hole_fraction,
        tiles,
        pixels_read_fraction,
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
