//! The training loop: configuration, one step (forward, losses, backward, Adam), validation,
//! checkpoints and resume. Read top to bottom: [`TrainConfig`], [`train`], then its helpers.
//!
//! A run folder holds `config.toml` (the configuration as run), `metrics.csv`, `loss.png`,
//! `checkpoints/step_NNNNNNNN.safetensors` (the last `keep_checkpoints`) and, at the end,
//! `model.safetensors`. The batch of step `s` is a function of the seed and `s` alone, and every
//! operator reduces in a fixed order, so a resumed run continues bit-identically.
//!
//! The same loop runs as one rank of a data-parallel job ([`train_on`], `mpirun -np N ivp train`):
//! each rank trains on its part of every batch, the ranks' gradients are summed before Adam's
//! step (see [`crate::distributed`]), and rank 0 alone reads and writes the run folder.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, ensure, Context, Result};
use candle_core::backprop::GradStore;
use candle_core::{Tensor, Var};
use candle_nn::VarMap;
use ivp_core::nn::loss::{ivp_loss_normalised, LossCounts, LossWeights};
use ivp_core::nn::model::{named_parameters, IvpNet, ModelConfig, NetInput, Variant};
use ivp_core::nn::optim::{Adam, AdamConfig};
use ivp_data::samples::{
    Batch, ClipSource, DatasetSource, SampleConfig, SampleGenerator, SampleStream, Split, StreamOptions,
    SyntheticSource,
};
use ivp_data::{check_probability, SceneParams};
use serde::{Deserialize, Serialize};

use crate::checkpoint::{
    check_depth_head_mult, check_width_mult, export_model, load_checkpoint, load_model, mean_of, network_from,
    save_checkpoint, Checkpoint,
};
use crate::distributed::{
    any_rank, batch_part, broadcast_from_root, f32_bytes, share_training_state, sum_gradients, sum_over_ranks,
    tensor_from_f32_bytes, ProcessGroup, SingleProcess,
};
use crate::eval::{DEFAULT_TARGETS, FIRST_TARGET};
use crate::guide::{Guide, GuideChoice, GuideSource, GuideTarget};
use crate::metrics_csv::{d_mse_as_logged, LossWindow, MetricsLog, MetricsRow};
use crate::plot::{write_loss_curve, Marks};
use crate::progress::progress_bar;
use crate::validation::{ValidationConfig, ValidationReport, ValidationSet, REPOSITORY_CLIPS};

/// What [`training_step`] returns; it lives with the rows of `metrics.csv` that hold its means.
pub use crate::metrics_csv::LossValues;

/// Everything that defines a training run. The defaults are the 30-minute recipe for 2 cores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// A dataset folder of clips; `None` trains on generated scenes.
    pub data: Option<PathBuf>,
    /// `full`, `intensity`, `no-tg` or `no-depth`.
    pub variant: Variant,
    pub width_mult: f64,
    /// Scales the depth head's widths (16, 32, 16); 1 is the paper's head. The recipe scales it
    /// like the network (0.25: 4, 8, 4): over five seeds it scores as the paper's head does, within
    /// their spread, and takes 29% off the network's time at 1080p (results/recipe-hd/depth-head).
    pub depth_head_mult: f64,
    pub steps: u64,
    pub batch: usize,
    pub crop: usize,
    /// Generated clips are rendered at 320x240 times one of these, drawn per clip: the same
    /// motion then opens holes this many times wider in pixels, as larger frames do
    /// (`SyntheticSource::with_scales`). Ignored with `data`.
    pub frame_scales: Vec<usize>,
    /// Generated clips move the camera this many times the head motion of a 30 fps display per
    /// frame, one factor drawn per clip: larger motion opens wider holes at the same frame size
    /// (`SyntheticSource::with_motion_scales`). Ignored with `data`.
    pub motion_scales: Vec<f64>,
    /// Probability that a near object of a generated scene is a floor-to-ceiling column or pole
    /// (`SceneParams::near_column_probability`), from the fraction `near_column_probability_from`
    /// of the run on; before it, none is. Ignored with `data`.
    /// The recipe's 0.5 from half-way, with `mse_weight` 10 from there: over five seeds 502.6 ±
    /// 14.7 D-MSE on the 12 real clips at 320x240 and 542.8 ± 14.5 at 1080p, against 534.2 ± 16.2
    /// and 550.0 ± 14.3 for the recipe before (no columns, weight 5), and 517.3 ± 13.7 and 547.4 ±
    /// 13.0 with the columns alone (results/recipe-hd). Another draw of the second halves' batches
    /// scores 512.3 and 554.0: over both draws, 5% lower at 320x240 and even at 1080p. Columns
    /// from the start: 2.4% lower at 320x240 than without, but 0.9% higher at 1080p with the
    /// seeds 15.3% apart there.
    pub near_column_probability: f64,
    /// The fraction of `steps` from which generated scenes hold near columns; the data of the
    /// steps before it are the scenes without them, whatever `near_column_probability` says.
    pub near_column_probability_from: f64,
    /// Probability that a texture of a generated scene is 2 to 4 times finer than the default
    /// patterns (`SceneParams::fine_texture_probability`). Ignored with `data`.
    pub fine_texture_probability: f64,
    /// Steps during which a guide term pulls the vectors towards a target, fading linearly to
    /// nothing (0: the paper's losses alone from the start). See [`GuideSource`].
    pub guide_steps: u64,
    /// The guide's target: `auto` (from what the variant reads), `fill` or `prior` ([`GuideChoice`]).
    pub guide: GuideChoice,
    /// Weight of the MSE term of the loss, beside 1 for the SSIM term and 0.001 for smoothness
    /// (ALGORITHMS.md §6.4; the paper's: 1), from the fraction `mse_weight_from` of the run on.
    /// The recipe's 10 from half-way, with the near columns that begin there: see
    /// `near_column_probability`. 5 from half-way (the recipe before) put every seed of five lower
    /// in D-MSE than the paper's weights on real clips at 320x240, and even at 1080p. At 5 or 10
    /// from the start one seed of five and one of three copied the foreground into some clips'
    /// holes, and at 30 the one run tried did everywhere (results/recipe-hd).
    pub mse_weight: f64,
    /// The fraction of `steps` from which the MSE term takes `mse_weight`; before it, the
    /// paper's 1. The heavier term then refines a model whose vectors the paper's loss has already
    /// laid out, and no seed measured copies the foreground.
    pub mse_weight_from: f64,
    /// Weight of the foreground guard, at every step (0: none): a guide term towards the `fill`
    /// vectors on the disocclusion pixels whose vector reads a known pixel nearer than the pixel's
    /// background depth threshold (ALGORITHMS.md §6.5), divided by all disocclusion pixels. For
    /// the variants that read depth. See `GuideTarget::at_foreground_reads`.
    pub foreground_guard: f64,
    /// Peak learning rate of Adam.
    pub lr: f64,
    /// Gradients whose global norm exceeds this are scaled down to it before Adam's update (0:
    /// never): without it one gradient of norm 6 ruined a seed of the recipe (results/recipe-hd).
    /// metrics.csv logs the largest norm of each window (`max_grad_norm`).
    pub max_grad_norm: f64,
    /// A validation of a checkpointed step whose D-MSE on the generated 320x240 frames is more
    /// than this fraction above the lowest before it rolls training back to the checkpoint
    /// validated before it (0: never): the run goes on from those parameters and Adam's state
    /// with the batches of the steps after the failed validation. One run of the recipe in ten
    /// left its basin at step 1250 and never came back (1080p 1.17x `fill`; its generated
    /// validation 5.7% above its lowest), while no run that kept its basin rose 0.5% above
    /// its lowest (results/recipe-hd/avx512).
    pub rollback_above: f64,
    /// Steps of linear warm-up from 0 to `lr`.
    pub warmup_steps: u64,
    /// Learning rate at the last step, as a fraction of `lr` (cosine decay after the warm-up;
    /// 1 keeps it constant).
    pub final_lr_fraction: f64,
    pub seed: u64,
    /// Steps between two log rows of `metrics.csv` (training losses averaged over them).
    pub log_every: u64,
    /// Steps between two validations (0: only at the end).
    pub validate_every: u64,
    /// The seed of the generated validation clips: keep it fixed to compare runs, whatever their
    /// `seed` (validation.rs).
    pub validation_seed: u64,
    /// Validation clips of 12 frames at 320x240 (3 targets each).
    pub validation_clips: usize,
    /// Validation clips of 6 frames at 1920x1080 (3 targets each).
    pub validation_hd_clips: usize,
    /// A folder of real clips (12 frames or more) scored at every validation beside the generated
    /// ones, at `validation_targets`: of what a run prints, the figure closest to real renders,
    /// and what chooses the model when `select_from` is below 1. By default the repository's 12
    /// Blender clips (`data`, relative to the working folder; skipped with a warning when it is
    /// missing or holds no clip), scored as `ivp eval --data data` scores them: the recipe
    /// chooses nothing by them, and a run prints the figure its model is judged by. With
    /// `select_from` below 1, point it at clips you will not judge the model on (`cargo xtask
    /// ablate` validates on `blender-dev-extra` and judges on `blender-dev`).
    pub validation_data: Option<PathBuf>,
    /// The targets scored in each clip of `validation_data`: by default `ivp eval`'s, 6, 8 and 10
    /// (36 frames of the 12 clips). Every target from 3 to 11 of the 4 `blender-dev` clips
    /// ranked 25 trained models as the 8 `blender-dev-extra` clips do at Spearman 0.69, their
    /// targets 6, 8 and 10 at 0.48 (results/recipe-hd/README.md): for a choice by a few clips,
    /// more targets help.
    pub validation_targets: Vec<usize>,
    /// Iterations of the test-time infilling in validation (ALGORITHMS.md §6.5).
    pub iterations: usize,
    /// Steps between two checkpoints.
    pub checkpoint_every: u64,
    /// Checkpoints kept in `checkpoints/` (older ones are deleted).
    pub keep_checkpoints: usize,
    /// The model file is the mean of the parameters of this many consecutive checkpoints,
    /// `checkpoint_every` steps apart (its *window*; 1: one checkpoint): the last window, or the
    /// one `select_from` chooses. The recipe's 9 are steps 3000-5000: single checkpoints 250
    /// steps apart differ at 1080p by as much as seeds do (500-620 D-MSE for one seed), and the
    /// mean of the last 9 brought five seeds within 3.8% of each other there (results/recipe-hd,
    /// "Thin runs"). A run of fewer steps averages from its first checkpoint on (the demo's 1000
    /// steps take 1). Must not exceed `keep_checkpoints`.
    pub average_checkpoints: usize,
    /// Below 1, with `validation_data`: the model file is the window that scored the lowest D-MSE
    /// on those real clips among the validations from this fraction of `steps` on (the last
    /// step's among them); from then on, the validation of a checkpointed step scores the mean of
    /// the window that ends there (metrics.csv logs it). 1 (the recipe), or no `validation_data`:
    /// the last window. With the thin-run rule (ALGORITHMS.md §6.5) the windows of a run score
    /// within 0.5% of each other on the real clips, so that choice follows noise, while their
    /// 1080p scores spread by 20% (results/recipe-hd, "Thin runs").
    pub select_from: f64,
    /// Background threads that make batches.
    pub data_workers: usize,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            data: None,
            variant: Variant::Full,
            width_mult: 0.25,
            depth_head_mult: 0.25,
            steps: 5000,
            batch: 16,
            crop: 64,
            frame_scales: vec![1],
            motion_scales: vec![1.0],
            near_column_probability: 0.5,
            near_column_probability_from: 0.5,
            fine_texture_probability: 0.0,
            guide_steps: 500,
            guide: GuideChoice::Auto,
            mse_weight: 10.0,
            mse_weight_from: 0.5,
            foreground_guard: 0.0,
            lr: 1e-3,
            max_grad_norm: 1.0,
            rollback_above: 0.02,
            warmup_steps: 100,
            final_lr_fraction: 0.1,
            seed: 0,
            log_every: 25,
            validate_every: 250,
            validation_seed: 20_261_204,
            validation_clips: 8,
            validation_hd_clips: 2,
            validation_data: Some(PathBuf::from(REPOSITORY_CLIPS)),
            validation_targets: DEFAULT_TARGETS.to_vec(),
            iterations: ivp_core::infill::DEFAULT_ITERATIONS,
            checkpoint_every: 250,
            keep_checkpoints: 9,
            average_checkpoints: 9,
            select_from: 1.0,
            data_workers: 1,
        }
    }
}

/// The fields of [`TrainConfig`] that `ivp train` takes as flags, each named as its field. They
/// are applied by name through serde ([`TrainOverrides::apply`]), so the defaults and their
/// documentation stay on [`TrainConfig`] alone, and a flag whose field is renamed or removed fails
/// the tests rather than setting nothing.
#[derive(Clone, Debug, Default, PartialEq, clap::Args, Serialize)]
pub struct TrainOverrides {
    /// full, intensity, no-tg (zeros for the temporal prior) or no-depth (no depth head).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub variant: Option<Variant>,
    /// Width multiplier of the U-Net: 1 = the paper's widths (64 ... 256).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub width_mult: Option<f64>,
    /// Width multiplier of the depth head: 1 = the paper's widths (16, 32, 16) at any
    /// --width-mult (the recipe's is 0.25); below 1 the network is cheaper per pixel.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_head_mult: Option<f64>,
    /// Training steps.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps: Option<u64>,
    /// Crops per step (the global batch under MPI).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub batch: Option<usize>,
    /// Side of the square training crops, centred on a disocclusion.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub crop: Option<usize>,
    /// Peak learning rate of Adam, after a warm-up and before a cosine decay.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lr: Option<f64>,
    /// Weight of the MSE term of the loss beside 1 for the SSIM term (the paper's: 1).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mse_weight: Option<f64>,
    /// Weight of the foreground guard: pulls vectors that read the near object towards the
    /// background side, at every step (0: none).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub foreground_guard: Option<f64>,
    /// Seed of the data and of the initial weights: the same seed gives the same run.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Steps between checkpoints.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoint_every: Option<u64>,
    /// Steps between validations (0: only at the end).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validate_every: Option<u64>,
    /// A folder of real clips to validate on besides the generated frames (12 frames or more
    /// each; default: the repository's, `data`).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_data: Option<PathBuf>,
    /// The targets scored in each clip of --validation-data, comma-separated (default 6,8,10).
    #[arg(long, value_delimiter = ',')]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_targets: Option<Vec<usize>>,
}

impl TrainOverrides {
    /// `config` with the fields given here replaced.
    pub fn apply(&self, config: &TrainConfig) -> Result<TrainConfig> {
        let mut fields = serde_json::to_value(config)?;
        let serde_json::Value::Object(overrides) = serde_json::to_value(self)? else {
            unreachable!("a struct serialises to an object")
        };
        fields.as_object_mut().expect("a struct serialises to an object").extend(overrides);
        serde_json::from_value(fields).context("a command-line override names no training setting")
    }
}

impl TrainConfig {
    /// The few-minute run of `ivp demo`: the default recipe, shorter, and without real clips to
    /// choose its model by, since the demo then scores it on the repository's clips.
    pub fn demo() -> Self {
        // A window of 3 checkpoints would span half of so short a run, at a high learning rate.
        Self {
            steps: 1000,
            guide_steps: 300,
            validate_every: 250,
            validation_data: None,
            average_checkpoints: 1,
            ..Self::default()
        }
    }

    /// Reads a TOML file of [`TrainConfig`] fields (any subset; the rest keep their defaults).
    pub fn from_toml_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("{}: not a valid training configuration", path.display()))
    }

    pub fn model(&self) -> Result<ModelConfig> {
        Ok(ModelConfig::new(self.variant, self.width_mult).with_depth_head_mult(self.depth_head_mult))
    }

    pub fn validate(&self) -> Result<()> {
        self.guide_source()?;
        check_width_mult(self.width_mult).map_err(anyhow::Error::msg)?;
        check_depth_head_mult(self.depth_head_mult).map_err(anyhow::Error::msg)?;
        ensure!(self.steps > 0, "steps must be at least 1");
        ensure!(self.batch > 0, "batch must be at least 1");
        ensure!(self.crop >= 16, "crop must be at least 16, got {}", self.crop);
        ensure!(
            !self.frame_scales.is_empty() && self.frame_scales.iter().all(|s| (1..=8).contains(s)),
            "frame_scales must be whole numbers from 1 to 8, got {:?}",
            self.frame_scales
        );
        ensure!(
            !self.motion_scales.is_empty() && self.motion_scales.iter().all(|&s| s > 0.0 && s <= 16.0),
            "motion_scales must be numbers above 0 and at most 16, got {:?}",
            self.motion_scales
        );
        check_probability(self.near_column_probability)
            .map_err(|problem| anyhow!("near_column_probability {problem}"))?;
        check_probability(self.fine_texture_probability)
            .map_err(|problem| anyhow!("fine_texture_probability {problem}"))?;
        ensure_non_negative("mse_weight", self.mse_weight)?;
        for (name, fraction) in [
            ("near_column_probability_from", self.near_column_probability_from),
            ("mse_weight_from", self.mse_weight_from),
        ] {
            ensure!((0.0..=1.0).contains(&fraction), "{name} must be in [0, 1] (a fraction of steps), got {fraction}");
        }
        ensure_non_negative("foreground_guard", self.foreground_guard)?;
        ensure!(
            self.foreground_guard == 0.0 || (self.variant.predicts_vectors() && self.variant.reads_depth()),
            "foreground_guard: variant {} does not read depth and predict vectors",
            self.variant
        );
        ensure!(self.lr > 0.0 && self.lr.is_finite(), "lr must be a positive number, got {}", self.lr);
        ensure_non_negative("max_grad_norm", self.max_grad_norm)?;
        ensure_non_negative("rollback_above", self.rollback_above)?;
        ensure!(
            (0.0..=1.0).contains(&self.final_lr_fraction),
            "final_lr_fraction must be in [0, 1], got {}",
            self.final_lr_fraction
        );
        ensure!(self.log_every > 0 && self.checkpoint_every > 0, "log_every and checkpoint_every must be at least 1");
        ensure!(self.keep_checkpoints > 0, "keep_checkpoints must be at least 1");
        ensure!(
            (1..=self.keep_checkpoints).contains(&self.average_checkpoints),
            "average_checkpoints must be from 1 to keep_checkpoints ({}), got {}",
            self.keep_checkpoints,
            self.average_checkpoints
        );
        ensure!((0.0..=1.0).contains(&self.select_from), "select_from must be in [0, 1], got {}", self.select_from);
        ensure!(self.iterations > 0, "iterations must be at least 1");
        ensure!(
            !self.validation_targets.is_empty() && self.validation_targets.iter().all(|&t| t >= FIRST_TARGET),
            "validation_targets must be frame indices of 3 or more (a target needs the 3 frames before it), got {:?}",
            self.validation_targets
        );
        Ok(())
    }

    /// Whether a run started with `saved` may go on with this configuration: it may change its
    /// length and what it records (how often it validates and checkpoints, how many checkpoints
    /// it keeps), which leave its parameters as they would be, not what it computes.
    pub fn may_continue(&self, saved: &TrainConfig) -> bool {
        let saved_but_recording = TrainConfig {
            steps: self.steps,
            validate_every: self.validate_every,
            checkpoint_every: self.checkpoint_every,
            keep_checkpoints: self.keep_checkpoints,
            ..saved.clone()
        };
        saved_but_recording == *self
    }

    /// The fields in which this configuration differs from `other`, as `name: other -> this`.
    pub fn changes_from(&self, other: &TrainConfig) -> Result<Vec<String>> {
        let (this, other) = (serde_json::to_value(self)?, serde_json::to_value(other)?);
        let (Some(this), Some(other)) = (this.as_object(), other.as_object()) else {
            bail!("a training configuration serialises as a map");
        };
        let null = serde_json::Value::Null;
        Ok(this
            .iter()
            .filter(|(name, value)| other.get(*name).unwrap_or(&null) != *value)
            .map(|(name, value)| format!("{name}: {} -> {value}", other.get(name).unwrap_or(&null)))
            .collect())
    }

    /// The first step whose checkpoint may become the model by its validation on real clips
    /// (`select_from`), or `None` when the model is the last step's.
    pub fn selection_start(&self) -> Option<u64> {
        let start = self.step_at(self.select_from);
        (self.validation_data.is_some() && start < self.steps).then_some(start)
    }

    /// The first step of the fraction `fraction` of the run on (`ceil(fraction * steps)`).
    fn step_at(&self, fraction: f64) -> u64 {
        (fraction * self.steps as f64).ceil() as u64
    }

    /// The step from which generated scenes hold near columns (`near_column_probability_from`).
    pub fn near_columns_start(&self) -> u64 {
        self.step_at(self.near_column_probability_from)
    }

    /// The step from which the MSE term takes `mse_weight` (`mse_weight_from`).
    fn mse_weight_start(&self) -> u64 {
        self.step_at(self.mse_weight_from)
    }

    /// The weights of the loss's terms at step `step` (0-based): the paper's, with the MSE term's
    /// `mse_weight` from the fraction `mse_weight_from` of the run on.
    pub fn loss_weights_at(&self, step: u64) -> LossWeights {
        let mse = if step >= self.mse_weight_start() { self.mse_weight } else { LossWeights::default().mse };
        LossWeights { mse, ..LossWeights::default() }
    }

    /// The target of the guide term (`None` for the variant without vectors).
    pub fn guide_source(&self) -> Result<Option<GuideSource>> {
        self.guide.source_for(self.variant)
    }

    /// The guide term of step `step`: its target, weighted 1 fading linearly to 0 at `guide_steps`.
    pub fn guide_at(&self, step: u64) -> Result<Guide> {
        Ok(Guide {
            source: self.guide_source()?,
            weight: self.guide_weight_at(step),
            foreground_guard: self.foreground_guard,
        })
    }

    /// The weight of the guide term at step `step`: 1 fading linearly to 0 at `guide_steps`.
    pub fn guide_weight_at(&self, step: u64) -> f64 {
        if step >= self.guide_steps {
            return 0.0;
        }
        1.0 - step as f64 / self.guide_steps as f64
    }

    /// The learning rate of step `step` (0-based): linear warm-up, then cosine decay to
    /// `lr * final_lr_fraction` at the last step.
    pub fn lr_at(&self, step: u64) -> f64 {
        if step < self.warmup_steps {
            return self.lr * (step + 1) as f64 / self.warmup_steps as f64;
        }
        let decay_steps = self.steps.saturating_sub(self.warmup_steps).max(1);
        let progress = ((step - self.warmup_steps) as f64 / decay_steps as f64).min(1.0);
        let cosine = 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        self.lr * (self.final_lr_fraction + (1.0 - self.final_lr_fraction) * cosine)
    }

    pub fn validation_config(&self) -> ValidationConfig {
        ValidationConfig {
            seed: self.validation_seed,
            clips: self.validation_clips,
            hd_clips: self.validation_hd_clips,
            data: self.validation_data.clone(),
            targets: self.validation_targets.clone(),
        }
    }

    fn sample_config(&self) -> SampleConfig {
        SampleConfig { seed: self.seed, crop: self.crop, batch_size: self.batch, ..SampleConfig::default() }
    }

    /// The generated scenes of step `step`: rendered at twice the crop (at least 320x240), with
    /// near columns from `near_columns_start` on.
    pub fn scene_params_at(&self, step: u64) -> SceneParams {
        SceneParams {
            width: (2 * self.crop).max(320),
            height: (3 * self.crop / 2).max(240),
            near_column_probability: match step >= self.near_columns_start() {
                true => self.near_column_probability,
                false => 0.0,
            },
            fine_texture_probability: self.fine_texture_probability,
            ..SceneParams::default()
        }
    }

    /// Whether the clips change at `step`: generated scenes whose near columns begin there.
    fn scenes_change_at(&self, step: u64) -> bool {
        self.data.is_none() && self.near_column_probability > 0.0 && step == self.near_columns_start()
    }

    /// The steps inside the run where what it trains on or how changes, each with what changes
    /// there, in order of step (changes at the same step share one entry). `loss.png` marks
    /// them: the total loss jumps where the MSE term's weight does.
    pub fn schedule_changes(&self) -> Vec<(u64, String)> {
        let inside = |step: u64| step > 0 && step < self.steps;
        let mut changes: Vec<(u64, String)> = Vec::new();
        if self.guide_source().ok().flatten().is_some() && inside(self.guide_steps) {
            changes.push((self.guide_steps, "guide term off".into()));
        }
        let mse_from = self.mse_weight_start();
        if self.mse_weight != LossWeights::default().mse && inside(mse_from) {
            changes.push((mse_from, format!("MSE term x{}", self.mse_weight)));
        }
        let columns_from = self.near_columns_start();
        if self.scenes_change_at(columns_from) && inside(columns_from) {
            changes.push((columns_from, "near columns".into()));
        }
        if let Some(start) = self.selection_start().filter(|&s| inside(s)) {
            changes.push((start, "model chosen from here".into()));
        }
        changes.sort_by_key(|c| c.0);
        let mut merged: Vec<(u64, String)> = Vec::new();
        for (step, what) in changes {
            match merged.last_mut() {
                Some((last, text)) if *last == step => *text = format!("{text}, {what}"),
                _ => merged.push((step, what)),
            }
        }
        merged
    }

    /// Where the clips of step `step` come from: the dataset, or [`TrainConfig::scene_params_at`].
    fn source_at(&self, step: u64) -> Result<Arc<dyn ClipSource>> {
        Ok(match &self.data {
            Some(dir) => Arc::new(DatasetSource::open(dir)?),
            None => Arc::new(
                SyntheticSource::new(self.scene_params_at(step))
                    .with_scales(&self.frame_scales)
                    .with_motion_scales(&self.motion_scales),
            ),
        })
    }
}

/// How a run starts, and how it is watched and stopped (which changes nothing in its results).
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Continue from the last checkpoint of the run folder.
    pub resume: bool,
    /// Start a new run from this checkpoint of another run: its parameters, Adam's state and
    /// step, with this run's configuration from that step on (a branch of the other run).
    pub branch_from: Option<PathBuf>,
    pub progress: bool,
    /// Set (by Ctrl-C) to stop after the current step with a checkpoint.
    pub stop: Option<Arc<AtomicBool>>,
    /// Stop after this step with a checkpoint, as Ctrl-C does (to train in several sittings).
    pub stop_at: Option<u64>,
}

/// What a finished (or stopped) run reports.
#[derive(Clone, Debug)]
pub struct TrainSummary {
    /// The step the run stopped at (its last step unless stopped early).
    pub steps_done: u64,
    /// The steps this call ran (fewer than `steps_done` when resumed).
    pub steps_run: u64,
    pub stopped_early: bool,
    pub elapsed: Duration,
    /// The validation of the model file (of the last step when stopped early).
    pub last_validation: Option<ValidationReport>,
    pub fill: Option<ValidationReport>,
    pub model_path: Option<PathBuf>,
    /// The steps whose parameters the model file averages (its window; one step: that step's
    /// parameters). Empty when stopped early, and on ranks other than 0.
    pub model_steps: Vec<u64>,
}

/// Trains a network as `config` says, in `run_dir`.
pub fn train(config: &TrainConfig, run_dir: &Path, options: &RunOptions) -> Result<TrainSummary> {
    train_on(&SingleProcess, config, run_dir, options)
}

/// [`train`] as one rank of a data-parallel job: every rank of `group` calls it with the same
/// configuration. `config.batch` is the global batch, split over the ranks; rank 0 alone reads and
/// writes `run_dir` (the others start from its state) and shows progress.
pub fn train_on(
    group: &dyn ProcessGroup,
    config: &TrainConfig,
    run_dir: &Path,
    options: &RunOptions,
) -> Result<TrainSummary> {
    config.validate()?;
    let model_config = config.model()?;
    let is_root = group.rank() == 0;
    let batch_part = batch_part(config.batch, group)?;
    let checkpoints = run_dir.join("checkpoints");

    let (net, varmap) = IvpNet::seeded(model_config, config.seed)?;
    let max_grad_norm = (config.max_grad_norm > 0.0).then_some(config.max_grad_norm);
    let mut optimizer =
        Adam::new(named_parameters(&varmap), AdamConfig { lr: config.lr, max_grad_norm, ..AdamConfig::default() })?;
    let _lock = is_root.then(|| lock_run_folder(run_dir)).transpose()?;
    let mut run = match is_root {
        true => Some(open_run_folder(config, run_dir, options, &varmap, &mut optimizer)?),
        false => None,
    };
    let mut selection = Selection::new(config);
    let mut guard = DivergenceGuard::new(config);
    if let Some(run) = &run {
        selection.recall(config, run.log.rows(), &checkpoints);
        guard.recall(config, run.log.rows());
    }
    let first_step = share_training_state(group, &mut optimizer, run.as_ref().map_or(0, |r| r.first_step))?;
    let elapsed_before = run.as_ref().map_or(Duration::ZERO, |r| r.log.last_elapsed());
    let config_json = serde_json::to_string(config)?;

    let validation = ValidationSet::new(&config.validation_config())?;
    let fill = validation.score_fill(group)?;
    // The samples of a step are a function of the step and the source alone: a stream started
    // afresh where the scenes change gives the same batches whether the run went through that step
    // or resumed there.
    let stream_from = |step: u64| -> Result<SampleStream> {
        let generator = SampleGenerator::new(config.source_at(step)?, config.sample_config(), Split::Train)?
            .with_batch_part(batch_part.clone())?;
        let options = StreamOptions { workers: config.data_workers, ..Default::default() };
        Ok(SampleStream::start(Arc::new(generator), step, options)?)
    };
    let mut stream = stream_from(first_step)?;

    let bar = progress_bar(options.progress && is_root, config.steps, "training");
    bar.set_position(first_step);
    let start = Instant::now();
    let elapsed = || elapsed_before + start.elapsed();
    let mut window = LossWindow::default();
    let mut last_validation = None;
    let mut step = first_step;
    let mut stopped_early = false;
    // Keeps the windows of `step` (the next window needs its checkpoints) and of the best step.
    let checkpoint = |step: u64, optimizer: &Adam, best: Option<u64>| -> Result<()> {
        if !is_root {
            return Ok(());
        }
        let path = checkpoint_path(&checkpoints, step);
        save_checkpoint(&path, &varmap, &model_config, optimizer, step, &config_json)?;
        tracing::info!(step, path = %path.display(), "checkpoint");
        let mut protect = window_steps(config, step);
        protect.extend(best.map(|best| window_steps(config, best)).unwrap_or_default());
        prune_checkpoints(&checkpoints, config.keep_checkpoints, &protect)
    };
    while step < config.steps {
        if config.scenes_change_at(step) && step != first_step {
            let p = config.near_column_probability;
            tracing::info!(step, "generated scenes from here on: near columns with probability {p}");
            stream = stream_from(step)?;
        }
        let batch = stream.next_batch()?;
        debug_assert_eq!(batch.step, step);
        optimizer.set_lr(config.lr_at(step));
        let guide = config.guide_at(step)?;
        let weights = config.loss_weights_at(step);
        let loss = training_step(&net, &mut optimizer, &batch_input(&batch), &batch.truth, &weights, guide, group)
            .with_context(|| format!("training stopped at step {step}; the last good checkpoint is kept"))?;
        step += 1;
        window.add(&loss);
        bar.set_position(step);
        let samples_per_s = (step - first_step) as f64 * config.batch as f64 / start.elapsed().as_secs_f64();
        bar.set_message(format!("loss {:.4}, {samples_per_s:.1} samples/s", loss.total));

        let validate_now = (config.validate_every > 0 && step % config.validate_every == 0) || step == config.steps;
        if step % config.log_every == 0 || validate_now {
            let scores = validate_now
                .then(|| {
                    let scored = match selection.scores_window(config, step) {
                        true => window_network(group, config, &checkpoints, step, &varmap, model_config)?,
                        false => net.clone(),
                    };
                    validation.score_network(&scored, config.iterations, group)
                })
                .transpose()?;
            if let Some(s) = &scores {
                let line = s.describe(&fill);
                tracing::info!(step, "validation: {line}");
                bar.println(format!("step {step}: validation {line}"));
                last_validation = Some(*s);
                if is_checkpoint_step(config, step) {
                    match guard.check(step, s) {
                        Some(good) => {
                            let restored = roll_back(group, &checkpoints, good, &varmap, &mut optimizer)?;
                            if is_root {
                                let line = match restored {
                                    true => format!("rolled back to the checkpoint of step {good}"),
                                    false => format!("cannot roll back: no checkpoint of step {good}"),
                                };
                                tracing::warn!(step, "training diverged (320x240 D-MSE above its lowest): {line}");
                                bar.println(format!("step {step}: training diverged, {line}"));
                            }
                        }
                        None => selection.offer(step, s),
                    }
                }
            }
            if let Some(run) = &mut run {
                run.log.push(MetricsRow { step, loss: window.take(), validation: scores, fill, elapsed: elapsed() });
                run.log.save()?;
            }
        }
        if is_checkpoint_step(config, step) {
            checkpoint(step, &optimizer, selection.step())?;
        }
        // Ctrl-C reaches the ranks one by one (or only one): they stop together, after the same step.
        let interrupted = any_rank(group, options.stop.as_ref().is_some_and(|s| s.load(Ordering::SeqCst)));
        if (interrupted || options.stop_at == Some(step)) && step < config.steps {
            if !is_checkpoint_step(config, step) {
                checkpoint(step, &optimizer, selection.step())?;
            }
            bar.println(format!("stopped at step {step}; continue with --resume"));
            stopped_early = true;
            break;
        }
    }
    bar.finish_and_clear();
    drop(stream);
    let model_path = (!stopped_early).then(|| run_dir.join("model.safetensors"));
    let mut model_steps = Vec::new();
    if let Some(run) = &mut run {
        if let Some(path) = &model_path {
            if let Some((best, scores)) = selection.best {
                export_model(&window_paths(config, &checkpoints, best), path)?;
                let real = config.validation_data.as_deref().unwrap_or(Path::new("")).display();
                bar.println(format!(
                    "model = {}, the lowest D-MSE on {real} since step {}: validation {}",
                    describe_model_steps(&window_steps(config, best)),
                    selection.start.unwrap_or(0),
                    scores.describe(&fill)
                ));
                last_validation = Some(scores);
                model_steps = window_steps(config, best);
            } else {
                if let Some(scores) = write_model(config, &checkpoints, step, path, &validation, &mut run.log)? {
                    let model = describe_model_steps(&window_steps(config, step));
                    bar.println(format!("model = {model}: validation {}", scores.describe(&fill)));
                    last_validation = Some(scores);
                }
                model_steps = window_steps(config, step);
            }
        }
        let marks = Marks { changes: config.schedule_changes(), model_steps: model_steps.clone() };
        write_loss_curve(&run_dir.join("loss.png"), run.log.rows(), &marks)?;
    }
    Ok(TrainSummary {
        steps_done: step,
        steps_run: step - first_step,
        stopped_early,
        elapsed: elapsed(),
        last_validation,
        fill: Some(fill),
        model_path,
        model_steps,
    })
}

/// The window that becomes the model when it is chosen by its validation on real clips
/// ([`TrainConfig::select_from`]): the lowest real-clip D-MSE among the validations of
/// checkpointed steps from `start` on, each of the window that ends there. Its checkpoints are
/// never pruned.
#[derive(Clone, Copy, Debug)]
struct Selection {
    start: Option<u64>,
    best: Option<(u64, ValidationReport)>,
}

impl Selection {
    fn new(config: &TrainConfig) -> Self {
        Self { start: config.selection_start(), best: None }
    }

    /// The last step of the best window so far.
    fn step(&self) -> Option<u64> {
        self.best.map(|(step, _)| step)
    }

    /// Whether the validation of step `step` scores the mean of its window rather than the
    /// parameters being trained: from the start of the choice on, at checkpointed steps.
    fn scores_window(&self, config: &TrainConfig, step: u64) -> bool {
        config.average_checkpoints > 1
            && self.start.is_some_and(|start| step >= start)
            && is_checkpoint_step(config, step)
    }

    /// Takes the validation of the window that ends at checkpointed step `step` if it is the best
    /// so far. Scores are compared as `metrics.csv` logs them, so that a resumed run, which recalls
    /// them from the file, chooses as an uninterrupted one does; a tie keeps the earlier step.
    fn offer(&mut self, step: u64, report: &ValidationReport) {
        let (Some(start), Some(real)) = (self.start, report.real) else { return };
        let best_d_mse = self.best.and_then(|(_, b)| b.real).map_or(f64::INFINITY, |b| d_mse_as_logged(b.d_mse));
        if step >= start && d_mse_as_logged(real.d_mse) < best_d_mse {
            self.best = Some((step, *report));
        }
    }

    /// On resume: the best of the validations logged before, among the checkpoints still on disk.
    fn recall(&mut self, config: &TrainConfig, rows: &[MetricsRow], checkpoints: &Path) {
        for row in rows {
            if let Some(report) = &row.validation {
                if is_checkpoint_step(config, row.step)
                    && window_paths(config, checkpoints, row.step).iter().all(|path| path.is_file())
                {
                    self.offer(row.step, report);
                }
            }
        }
    }
}

/// Rolls a diverged run back ([`TrainConfig::rollback_above`]): the lowest D-MSE on the generated
/// 320x240 frames among the validations of checkpointed steps, compared as `metrics.csv` logs
/// them so that a resumed run decides as an uninterrupted one did.
#[derive(Clone, Copy, Debug)]
struct DivergenceGuard {
    above: f64,
    lowest: f64,
    last_checkpoint: Option<u64>,
}

impl DivergenceGuard {
    fn new(config: &TrainConfig) -> Self {
        Self { above: config.rollback_above, lowest: f64::INFINITY, last_checkpoint: None }
    }

    /// Takes the validation of checkpointed step `step`: the step to roll back to (the checkpoint
    /// validated before it) when it left the lowest by more than the tolerance. After a rollback
    /// the checkpoint of `step` holds the restored state, so it is the next one to return to.
    fn check(&mut self, step: u64, report: &ValidationReport) -> Option<u64> {
        let before = self.last_checkpoint.replace(step);
        let d_mse = d_mse_as_logged(report.small?.d_mse);
        if self.above > 0.0 && d_mse > self.lowest * (1.0 + self.above) {
            return before;
        }
        self.lowest = self.lowest.min(d_mse);
        None
    }

    /// On resume: the validations logged before, in order.
    fn recall(&mut self, config: &TrainConfig, rows: &[MetricsRow]) {
        for row in rows {
            if let (Some(report), true) = (&row.validation, is_checkpoint_step(config, row.step)) {
                self.check(row.step, report);
            }
        }
    }
}

/// Restores the parameters and Adam's state of the checkpoint of step `step` on every rank (rank
/// 0 reads it); whether it was there to restore.
fn roll_back(
    group: &dyn ProcessGroup,
    checkpoints: &Path,
    step: u64,
    varmap: &VarMap,
    optimizer: &mut Adam,
) -> Result<bool> {
    let path = checkpoint_path(checkpoints, step);
    let restored = group.rank() == 0 && path.is_file();
    if restored {
        load_checkpoint(&path)?.restore_into(&path, varmap, optimizer)?;
    }
    share_training_state(group, optimizer, step)?;
    Ok(restored)
}

/// Whether the run writes a checkpoint after step `step`.
fn is_checkpoint_step(config: &TrainConfig, step: u64) -> bool {
    step.is_multiple_of(config.checkpoint_every) || step == config.steps
}

fn checkpoint_path(checkpoints: &Path, step: u64) -> PathBuf {
    checkpoints.join(format!("step_{step:08}.safetensors"))
}

/// The step of a checkpoint file named as [`checkpoint_path`] names them.
pub fn checkpoint_step(path: &Path) -> Option<u64> {
    let name = path.file_name()?.to_str()?;
    name.strip_prefix("step_")?.strip_suffix(".safetensors")?.parse().ok()
}

/// The steps of the window that ends at checkpointed step `step`: the `average_checkpoints - 1`
/// checkpointed steps before it, `checkpoint_every` apart, then `step` (fewer at the start of a
/// run). A checkpoint written off that grid, when a run is stopped, is in no window.
fn window_steps(config: &TrainConfig, step: u64) -> Vec<u64> {
    let every = config.checkpoint_every;
    let mut steps = vec![step];
    let mut before = step.saturating_sub(1) / every * every;
    while steps.len() < config.average_checkpoints && before > 0 {
        steps.push(before);
        before -= every;
    }
    steps.reverse();
    steps
}

fn window_paths(config: &TrainConfig, checkpoints: &Path, step: u64) -> Vec<PathBuf> {
    window_steps(config, step).into_iter().map(|s| checkpoint_path(checkpoints, s)).collect()
}

/// What a model of the parameters of `steps` is, as the run and `ivp train` print it: "the
/// parameters of step S" or "the mean of the parameters of steps A, B, S".
pub fn describe_model_steps(steps: &[u64]) -> String {
    match steps {
        [one] => format!("the parameters of step {one}"),
        steps => {
            let steps: Vec<String> = steps.iter().map(u64::to_string).collect();
            format!("the mean of the parameters of steps {}", steps.join(", "))
        }
    }
}

/// The network of the window that ends at `step`, on every rank: the mean ([`mean_of`], as
/// [`export_model`] takes it once `step`'s checkpoint is written, so the model file is the network
/// validated, to the bit) of the checkpoints of the steps before it, read by rank 0, which alone
/// reads the run folder, and of the parameters being trained, which are step `step`'s.
fn window_network(
    group: &dyn ProcessGroup,
    config: &TrainConfig,
    checkpoints: &Path,
    step: u64,
    varmap: &VarMap,
    model_config: ModelConfig,
) -> Result<IvpNet> {
    let current = named_parameters(varmap);
    let mut before = window_paths(config, checkpoints, step);
    before.pop();
    let mean_bytes = (group.rank() == 0)
        .then(|| -> Result<Vec<u8>> {
            let mut sets = Vec::new();
            for path in &before {
                let params = load_checkpoint(path)?.params;
                if let Some((name, _)) = current.iter().find(|(name, _)| !params.contains_key(name)) {
                    bail!("{}: no parameter `{name}`", path.display());
                }
                sets.push(params);
            }
            sets.push(current.iter().map(|(name, var)| (name.clone(), var.as_tensor().clone())).collect());
            let mean = mean_of(&sets)?;
            Ok(f32_bytes(&current.iter().map(|(name, _)| mean[name].clone()).collect::<Vec<_>>())?)
        })
        .transpose()?;
    let bytes = broadcast_from_root(group, mean_bytes);
    let mut values = bytes.as_slice();
    let mut mean = std::collections::HashMap::new();
    for (name, var) in &current {
        mean.insert(name.clone(), tensor_from_f32_bytes(&mut values, var.as_tensor())?);
    }
    let name = checkpoint_path(checkpoints, step);
    Ok(network_from(&name, &mean, model_config)?.detached())
}

/// Writes the model file of a run finished at `step` whose model is not chosen by validation: the
/// window that ends there, which is then validated too when it is a mean (its scores are returned
/// and logged as a row of the last step; `None` for the last step alone).
fn write_model(
    config: &TrainConfig,
    checkpoints: &Path,
    step: u64,
    path: &Path,
    validation: &ValidationSet,
    log: &mut MetricsLog,
) -> Result<Option<ValidationReport>> {
    let window = window_paths(config, checkpoints, step);
    if let Some(missing) = window.iter().find(|p| !p.is_file()) {
        bail!("{}: a checkpoint of the model's window is missing", missing.display());
    }
    export_model(&window, path)?;
    if window.len() == 1 {
        return Ok(None);
    }
    let (net, _) = load_model(path)?;
    let scores = validation.score_network(&net, config.iterations, &SingleProcess)?;
    if let Some(row) = log.last_mut() {
        row.validation = Some(scores);
    }
    log.save()?;
    Ok(Some(scores))
}

/// Holds `run_dir/.lock` for the life of the run: a second `ivp train` into the same folder,
/// which would race this one's checkpoints and log, fails at once.
fn lock_run_folder(run_dir: &Path) -> Result<std::fs::File> {
    std::fs::create_dir_all(run_dir).with_context(|| format!("cannot create {}", run_dir.display()))?;
    let path = run_dir.join(".lock");
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => {
            bail!("{}: another process is training in this folder", run_dir.display())
        }
        Err(std::fs::TryLockError::Error(e)) => Err(e).with_context(|| format!("cannot lock {}", path.display())),
    }
}

/// What rank 0 finds in (or starts) the run folder.
struct RunFolder {
    first_step: u64,
    log: MetricsLog,
}

/// Starts the run in `run_dir` (from `options.branch_from` when given), or (`options.resume`)
/// restores the parameters and Adam's state of its last checkpoint, which must be of the same
/// configuration but for what a run only records ([`TrainConfig::may_continue`]).
fn open_run_folder(
    config: &TrainConfig,
    run_dir: &Path,
    options: &RunOptions,
    varmap: &VarMap,
    optimizer: &mut Adam,
) -> Result<RunFolder> {
    let checkpoints = run_dir.join("checkpoints");
    std::fs::create_dir_all(&checkpoints).with_context(|| format!("cannot create {}", checkpoints.display()))?;
    let mut run = RunFolder { first_step: 0, log: MetricsLog::new(run_dir.join("metrics.csv")) };
    let resume = options.resume;
    ensure!(!(resume && options.branch_from.is_some()), "a run either resumes or branches from another run, not both");
    match (latest_checkpoint(&checkpoints)?, resume) {
        (Some(path), true) => {
            let ckpt = load_checkpoint(&path)?;
            let saved: TrainConfig = serde_json::from_str(&ckpt.train_config)
                .with_context(|| format!("{}: unreadable training configuration", path.display()))?;
            ensure!(
                config.may_continue(&saved),
                "{}: the run was started with another configuration (on resume only steps, validate_every, \
                 checkpoint_every and keep_checkpoints may change):\n{saved:#?}",
                path.display()
            );
            ckpt.restore_into(&path, varmap, optimizer)?;
            run.first_step = ckpt.step;
            run.log = MetricsLog::resume(run_dir.join("metrics.csv"), ckpt.step)?;
            tracing::info!("resuming {} at step {}", run_dir.display(), ckpt.step);
        }
        (None, true) => bail!("{}: nothing to resume (no checkpoint in {})", run_dir.display(), checkpoints.display()),
        (Some(path), false) => bail!(
            "{} already holds a run (last checkpoint {}): pass --resume to continue it, or choose another --out",
            run_dir.display(),
            path.display()
        ),
        (None, false) => {
            if let Some(source) = &options.branch_from {
                run = branch_from(config, source, run_dir, varmap, optimizer)?;
            }
        }
    }
    let config_text = toml::to_string(config)?;
    ivp_data::write_atomically(&run_dir.join("config.toml"), config_text.as_bytes())?;
    Ok(run)
}

/// Starts the run in `run_dir` at `source`, a checkpoint of another run: its parameters, Adam's
/// state and step. The source's checkpoints that the windows around that step average and its
/// `metrics.csv` up to the step come along, so that the run reads as the source until then; the
/// source's checkpoint is written again with this configuration, so that `--resume` continues the
/// branch. What the configuration changes is logged, not checked: a branch may change anything
/// but the network.
fn branch_from(
    config: &TrainConfig,
    source: &Path,
    run_dir: &Path,
    varmap: &VarMap,
    optimizer: &mut Adam,
) -> Result<RunFolder> {
    let ckpt = load_checkpoint(source)?;
    ensure!(
        ckpt.step < config.steps,
        "{}: a branch must start before the run's last step ({}), this checkpoint is of step {}",
        source.display(),
        config.steps,
        ckpt.step
    );
    let model_config = config.model()?;
    ensure!(
        ckpt.model == model_config,
        "{}: the checkpoint is of another network ({}; this run trains {model_config})",
        source.display(),
        ckpt.model
    );
    ckpt.restore_into(source, varmap, optimizer)?;
    tracing::info!("{}", describe_branch(config, source, &ckpt)?);

    let checkpoints = run_dir.join("checkpoints");
    let source_checkpoints = source.parent().unwrap_or(Path::new("."));
    // The windows that end after the branch's start reach back into the source's checkpoints:
    // those that may become the model or are validated as windows.
    let every = config.checkpoint_every;
    let used = |end: &u64| config.selection_start().map_or(*end == config.steps, |start| *end >= start);
    let window_ends = (1..=config.average_checkpoints as u64).map(|k| (ckpt.step / every + k) * every).filter(used);
    let mut needed: Vec<u64> =
        window_ends.flat_map(|end| window_steps(config, end)).filter(|&s| s < ckpt.step).collect();
    needed.sort_unstable();
    needed.dedup();
    let missing: Vec<u64> = needed.into_iter().filter(|&s| !checkpoint_path(source_checkpoints, s).is_file()).collect();
    ensure!(
        missing.is_empty(),
        "{}: the means of {} checkpoints after step {} need the source's checkpoints of steps {missing:?}, \
         which it no longer keeps (branch from a run that keeps more: keep_checkpoints)",
        source.display(),
        config.average_checkpoints,
        ckpt.step
    );
    let earliest = ckpt.step.saturating_sub((config.average_checkpoints as u64).saturating_sub(1) * every);
    for path in checkpoint_files(source_checkpoints)? {
        let step = checkpoint_step(&path);
        if step.is_some_and(|step| (earliest..ckpt.step).contains(&step)) {
            let bytes = std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
            ivp_data::write_atomically(&checkpoints.join(path.file_name().unwrap_or_default()), &bytes)?;
        }
    }
    let config_json = serde_json::to_string(config)?;
    save_checkpoint(
        &checkpoint_path(&checkpoints, ckpt.step),
        varmap,
        &model_config,
        optimizer,
        ckpt.step,
        &config_json,
    )?;

    let source_log = source_checkpoints.parent().unwrap_or(Path::new(".")).join("metrics.csv");
    let rows = match source_log.is_file() {
        true => MetricsLog::resume(source_log, ckpt.step)?.rows().to_vec(),
        false => {
            tracing::warn!(
                "{}: no metrics.csv beside the checkpoints; the log starts at step {}",
                source.display(),
                ckpt.step
            );
            Vec::new()
        }
    };
    let mut log = MetricsLog::new(run_dir.join("metrics.csv"));
    rows.into_iter().for_each(|row| log.push(row));
    Ok(RunFolder { first_step: ckpt.step, log })
}

/// "branching from SOURCE at step S; changed: name: before -> after, ...", from the checkpoint
/// `source` (loaded as `ckpt`).
pub fn describe_branch(config: &TrainConfig, source: &Path, ckpt: &Checkpoint) -> Result<String> {
    let saved: TrainConfig = serde_json::from_str(&ckpt.train_config)
        .with_context(|| format!("{}: unreadable training configuration", source.display()))?;
    let changes = config.changes_from(&saved)?;
    let changes = if changes.is_empty() { "nothing".to_string() } else { changes.join(", ") };
    Ok(format!("branching from {} at step {}; changed: {changes}", source.display(), ckpt.step))
}

/// `name` must be 0 or a positive, finite number (a weight, or a bound where 0 means none).
fn ensure_non_negative(name: &str, value: f64) -> Result<()> {
    ensure!(value >= 0.0 && value.is_finite(), "{name} must be 0 or a positive number, got {value}");
    Ok(())
}

/// One optimisation step on `input` with ground truth `truth`; returns the losses before the update.
/// `guide` is the guide term's target and weight (0 leaves it out); [`Guide::of`] gives the
/// variant's own, so that no variant learns through the loss from an input its ablation removes.
/// A non-finite loss is an error and leaves the parameters untouched.
///
/// In a data-parallel job `input` is this rank's part of the batch: its terms are divided by the
/// counts of the whole batch, the returned losses are the whole batch's and the update is the
/// same on every rank (for [`SingleProcess`] every exchange below returns its input as it is).
pub fn training_step(
    net: &IvpNet,
    optimizer: &mut Adam,
    input: &NetInput<'_>,
    truth: &Tensor,
    weights: &LossWeights,
    guide: Guide,
    group: &dyn ProcessGroup,
) -> Result<LossValues> {
    let (values, grads) = batch_gradients(net, optimizer.parameters(), input, truth, weights, guide, group)?;
    let grad_norm = optimizer.step(&grads)?;
    Ok(LossValues { grad_norm: grad_norm as f32, ..values })
}

/// The losses of the whole batch and the gradients of its loss (summed over the ranks) with
/// respect to `params`: everything of [`training_step`] but the update. Data parallelism is right
/// when these gradients equal one process's on the whole batch, to rounding.
pub fn batch_gradients(
    net: &IvpNet,
    params: &[(String, Var)],
    input: &NetInput<'_>,
    truth: &Tensor,
    weights: &LossWeights,
    guide: Guide,
    group: &dyn ProcessGroup,
) -> Result<(LossValues, GradStore)> {
    let guide_weight = guide.weight;
    let source = guide.source.filter(|_| guide_weight > 0.0);
    let guide_target = source.map(|source| GuideTarget::new(source, input)).transpose()?;
    let local = LossCounts::of(input.mask)?;
    let guide_count = guide_target.as_ref().map_or(0.0, |g| g.count);
    let [pixels, pairs_x, pairs_y, guide_count] =
        sum_over_ranks(group, &[local.pixels, local.pairs_x, local.pairs_y, guide_count]).try_into().expect("4 counts");
    let counts = LossCounts { pixels, pairs_x, pairs_y };

    let out = net.forward(input)?;
    let terms = ivp_loss_normalised(&out.frame, truth, input.mask, out.vectors.as_ref(), weights, &counts)?;
    let mut total = terms.total.clone();
    let mut guide_value = 0.0;
    if let (Some(vectors), Some(target)) = (&out.vectors, &guide_target) {
        let term = (target.loss(vectors, guide_count)? * guide_weight)?;
        guide_value = term.to_scalar::<f32>()?;
        total = (total + term)?;
    }
    if let Some(vectors) = out.vectors.as_ref().filter(|_| guide.foreground_guard > 0.0) {
        let fill = match (source, guide_target) {
            (Some(GuideSource::DepthFill), Some(target)) => target,
            _ => GuideTarget::new(GuideSource::DepthFill, input)?,
        };
        let guard = fill.at_foreground_reads(vectors, input.warped_depth)?;
        let term = (guard.loss(vectors, counts.pixels)? * guide.foreground_guard)?;
        guide_value += term.to_scalar::<f32>()?;
        total = (total + term)?;
    }
    let scalar = |t: &Tensor| -> Result<f64> { Ok(t.to_scalar::<f32>()? as f64) };
    let part = [scalar(&terms.mse)?, scalar(&terms.ssim)?, scalar(&terms.smooth)?, guide_value as f64, scalar(&total)?];
    let [mse, ssim, smooth, guide, total_value] = sum_over_ranks(group, &part).try_into().expect("5 terms");
    let values = LossValues {
        mse: mse as f32,
        ssim: ssim as f32,
        smooth: smooth as f32,
        guide: guide as f32,
        total: total_value as f32,
        grad_norm: 0.0,
    };
    if !values.total.is_finite() {
        bail!("the loss is not finite ({values:?})");
    }
    let mut grads = total.backward()?;
    sum_gradients(group, &mut grads, params)?;
    Ok((values, grads))
}

pub fn batch_input(batch: &Batch) -> NetInput<'_> {
    NetInput {
        prior: &batch.prior,
        warped_depth: &batch.warped_depth,
        mask: &batch.mask,
        warped: &batch.warped,
        last: Some(&batch.last),
        last_warped: Some(&batch.last_warped),
    }
}

/// The newest checkpoint of a folder, by step.
pub fn latest_checkpoint(dir: &Path) -> Result<Option<PathBuf>> {
    Ok(checkpoint_files(dir)?.pop())
}

/// Checkpoint files sorted by step (their names sort by step).
fn checkpoint_files(dir: &Path) -> Result<Vec<PathBuf>> {
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.starts_with("step_") && name.ends_with(".safetensors")
        })
        .collect();
    files.sort();
    Ok(files)
}

/// Deletes all but the last `keep` checkpoints and those of the steps in `protect`.
fn prune_checkpoints(dir: &Path, keep: usize, protect: &[u64]) -> Result<()> {
    let protected: Vec<PathBuf> = protect.iter().map(|&step| checkpoint_path(dir, step)).collect();
    let files = checkpoint_files(dir)?;
    for old in files[..files.len().saturating_sub(keep)].iter().filter(|f| !protected.contains(f)) {
        std::fs::remove_file(old).with_context(|| format!("cannot delete old checkpoint {}", old.display()))?;
    }
    Ok(())
}

/// The variables of a network, for callers that train outside [`train`] (tests, benchmarks).
pub fn seeded_network(config: &TrainConfig) -> Result<(IvpNet, VarMap)> {
    Ok(IvpNet::seeded(config.model()?, config.seed)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::validation::ValidationScores;

    #[test]
    fn the_guard_rolls_back_to_the_last_checkpoint_when_validation_leaves_its_lowest() {
        let small =
            |d_mse| ValidationReport { small: Some(ValidationScores { d_mse, d_ssim: 0.5 }), ..Default::default() };
        let mut guard = DivergenceGuard::new(&TrainConfig::default());
        assert_eq!(guard.check(250, &small(300.0)), None, "nothing to compare the first validation with");
        assert_eq!(guard.check(500, &small(290.0)), None);
        assert_eq!(guard.check(750, &small(295.8)), None, "2% above the lowest is within the tolerance");
        assert_eq!(guard.check(1000, &small(295.9)), Some(750));
        // The checkpoint of 1000 then holds 750's state: the next rollback returns there.
        assert_eq!(guard.check(1250, &small(400.0)), Some(1000));
        assert_eq!(guard.check(1500, &small(280.0)), None);
        assert_eq!(guard.check(1750, &small(290.0)), Some(1500), "the lowest is now 280");
        assert_eq!(guard.check(2000, &ValidationReport::default()), None, "no generated frames, no verdict");

        let off = TrainConfig { rollback_above: 0.0, ..TrainConfig::default() };
        let mut guard = DivergenceGuard::new(&off);
        assert_eq!(guard.check(250, &small(290.0)), None);
        assert_eq!(guard.check(500, &small(1e6)), None);
        assert!(TrainConfig { rollback_above: -0.1, ..off }.validate().is_err());
    }

    #[test]
    fn selection_keeps_the_lowest_real_clip_score_from_its_start() {
        let real =
            |d_mse| ValidationReport { real: Some(ValidationScores { d_mse, d_ssim: 0.5 }), ..Default::default() };
        let config =
            TrainConfig { steps: 100, select_from: 0.5, validation_data: Some("real".into()), ..Default::default() };
        assert_eq!(config.selection_start(), Some(50));
        let mut selection = Selection::new(&config);
        selection.offer(25, &real(1.0));
        assert_eq!(selection.step(), None, "before its start a step does not compete");
        selection.offer(50, &real(3.0));
        selection.offer(75, &real(2.0));
        selection.offer(100, &real(2.5));
        assert_eq!(selection.step(), Some(75));
        selection.offer(100, &ValidationReport::default());
        assert_eq!(selection.step(), Some(75), "a validation without real clips does not compete");

        // Compared as metrics.csv logs them (3 decimals), as a resumed run recalls them.
        let mut selection = Selection::new(&config);
        selection.offer(75, &real(1.9994));
        selection.offer(100, &real(1.9986));
        assert_eq!(selection.step(), Some(75), "equal as logged (1.999): the earlier step stays");

        for off in [TrainConfig { validation_data: None, ..config.clone() }, TrainConfig { select_from: 1.0, ..config }]
        {
            assert_eq!(off.selection_start(), None);
            let mut selection = Selection::new(&off);
            selection.offer(75, &real(2.0));
            assert_eq!(selection.step(), None);
        }
    }

    #[test]
    fn pruning_keeps_the_last_checkpoints_and_the_protected_one() {
        let dir = tempfile::tempdir().unwrap();
        for step in 1..=5 {
            std::fs::write(checkpoint_path(dir.path(), step), b"").unwrap();
        }
        prune_checkpoints(dir.path(), 2, &[2]).unwrap();
        let left: Vec<PathBuf> = [2, 4, 5].map(|s| checkpoint_path(dir.path(), s)).into();
        assert_eq!(checkpoint_files(dir.path()).unwrap(), left);
        prune_checkpoints(dir.path(), 2, &[5]).unwrap();
        let left: Vec<PathBuf> = [4, 5].map(|s| checkpoint_path(dir.path(), s)).into();
        assert_eq!(checkpoint_files(dir.path()).unwrap(), left, "a protected one among the last is not one more");
        prune_checkpoints(dir.path(), 1, &[]).unwrap();
        assert_eq!(checkpoint_files(dir.path()).unwrap(), [checkpoint_path(dir.path(), 5)]);
    }

    #[test]
    fn every_override_sets_the_field_of_its_name() {
        let recipe = TrainConfig::default();
        assert_eq!(TrainOverrides::default().apply(&recipe).unwrap(), recipe, "no flag, no change");
        let overrides = TrainOverrides {
            variant: Some(Variant::NoDepth),
            width_mult: Some(0.5),
            depth_head_mult: Some(0.5),
            steps: Some(7),
            batch: Some(3),
            crop: Some(32),
            lr: Some(2e-3),
            mse_weight: Some(3.0),
            foreground_guard: Some(0.5),
            seed: Some(9),
            checkpoint_every: Some(11),
            validate_every: Some(13),
            validation_data: Some(PathBuf::from("real")),
            validation_targets: Some(vec![6, 8, 10]),
        };
        let want = TrainConfig {
            variant: Variant::NoDepth,
            width_mult: 0.5,
            depth_head_mult: 0.5,
            steps: 7,
            batch: 3,
            crop: 32,
            lr: 2e-3,
            mse_weight: 3.0,
            foreground_guard: 0.5,
            seed: 9,
            checkpoint_every: 11,
            validate_every: 13,
            validation_data: Some(PathBuf::from("real")),
            validation_targets: vec![6, 8, 10],
            ..recipe.clone()
        };
        assert_eq!(overrides.apply(&recipe).unwrap(), want);
    }
    use candle_core::Device;

    fn tensor(v: Vec<f32>, shape: (usize, usize, usize, usize)) -> Tensor {
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    #[test]
    fn the_paper_recipe_reads_and_differs_from_the_default_as_documented() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recipes/paper.toml");
        let paper = TrainConfig::from_toml_file(&path).unwrap();
        paper.validate().unwrap();
        let expected = TrainConfig {
            width_mult: 1.0,
            depth_head_mult: 1.0,
            batch: 4,
            crop: 256,
            lr: 1e-4,
            warmup_steps: 0,
            final_lr_fraction: 1.0,
            guide_steps: 0,
            mse_weight: 1.0,
            near_column_probability: 0.0,
            ..TrainConfig::default()
        };
        assert_eq!(paper, expected);
    }

    /// A batch of 3 random 16x16 crops with holes and a prior: prior, depth, mask, warped, truth.
    fn toy_batch() -> [Tensor; 5] {
        let (b, h, w) = (3, 16, 16);
        let values = |c: usize, seed: usize| -> Vec<f32> {
            (0..b * c * h * w).map(|i| ((i * 7919 + seed * 104_729) % 1000) as f32 / 1000.0).collect()
        };
        // Crops with different numbers of hole pixels, so that a part's own counts are not the batch's.
        let mask: Vec<f32> = (0..b * h * w).map(|i| f32::from((i % (h * w)) / 16 % (5 + i / (h * w)) == 2)).collect();
        let prior: Vec<f32> =
            values(2, 1).iter().zip((0..).map(|i| mask[i % (b * h * w)])).map(|(v, m)| 4.0 * v * (1.0 - m)).collect();
        [prior, values(1, 2), mask, values(3, 3), values(3, 4)].map(|v| {
            let c = v.len() / (b * h * w);
            tensor(v, (b, c, h, w))
        })
    }

    /// Crops `part` of a batch of [`toy_batch`].
    fn part_of(batch: &[Tensor; 5], part: &std::ops::Range<usize>) -> [Tensor; 5] {
        batch.clone().map(|t| t.narrow(0, part.start, part.len()).unwrap())
    }

    /// The network's input from prior, depth, mask and warped frame of a [`toy_batch`].
    fn toy_input(t: &[Tensor; 5]) -> NetInput<'_> {
        NetInput { prior: &t[0], warped_depth: &t[1], mask: &t[2], warped: &t[3], last: None, last_warped: None }
    }

    #[test]
    fn the_ranks_summed_gradient_is_one_process_gradient_of_the_whole_batch() {
        use crate::distributed::tests::ThreadGroup;
        let batch = toy_batch();
        // The gradients of crops `part` of the batch, by `group`, one vector per parameter.
        let gradients = |group: &dyn ProcessGroup, part: std::ops::Range<usize>| -> Vec<Vec<f32>> {
            let t = part_of(&batch, &part);
            let (input, truth) = (toy_input(&t), &t[4]);
            let (net, varmap) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
            let params = named_parameters(&varmap);
            let guide = Guide { foreground_guard: 0.5, ..Guide::of(Variant::Full, 0.5) };
            let (_, grads) =
                batch_gradients(&net, &params, &input, truth, &LossWeights::default(), guide, group).unwrap();
            params.iter().map(|(_, v)| grads.get(v).unwrap().flatten_all().unwrap().to_vec1().unwrap()).collect()
        };
        // Equal to rounding: only the order of the additions differs.
        let agree = |a: &[Vec<f32>], b: &[Vec<f32>]| {
            let largest = a.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
            let worst = a.iter().flatten().zip(b.iter().flatten()).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
            worst <= 1e-5 * largest
        };
        let whole = gradients(&SingleProcess, 0..3);
        let ranks = ThreadGroup::run(2, |group| gradients(group, [0..2, 2..3][group.rank()].clone()));
        assert!(ranks[0] == ranks[1], "the ranks hold different gradients");
        assert!(agree(&whole, &ranks[0]), "the all-reduced gradient differs from one process's");

        // Negative controls: the ways data parallelism goes wrong must fail the same comparison.
        let dropped = gradients(&SingleProcess, 0..2);
        assert!(!agree(&whole, &dropped), "a dropped rank goes unnoticed");
        let (first, second) = (gradients(&SingleProcess, 0..2), gradients(&SingleProcess, 2..3));
        let unscaled: Vec<Vec<f32>> =
            first.iter().zip(&second).map(|(a, b)| a.iter().zip(b).map(|(x, y)| x + y).collect()).collect();
        assert!(!agree(&whole, &unscaled), "ranks that divide by their own counts go unnoticed");
        let doubled: Vec<Vec<f32>> = whole.iter().map(|g| g.iter().map(|x| 2.0 * x).collect()).collect();
        assert!(!agree(&whole, &doubled), "a gradient scaled by a constant goes unnoticed");
    }

    #[test]
    fn ranks_with_parts_of_a_batch_train_like_one_process_with_all_of_it() {
        use crate::distributed::tests::ThreadGroup;
        // 2 guided steps and 1 unguided, by one process and by 2 ranks (crops [0, 2) and [2, 3)).
        let batch = toy_batch();
        let train = |group: &dyn ProcessGroup, part: std::ops::Range<usize>| {
            let t = part_of(&batch, &part);
            let (input, truth) = (toy_input(&t), &t[4]);
            let (net, varmap) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
            let mut optimizer =
                Adam::new(named_parameters(&varmap), AdamConfig { lr: 1e-3, ..Default::default() }).unwrap();
            let losses: Vec<LossValues> = [1.0, 0.5, 0.0]
                .iter()
                .map(|&guide| {
                    let guide = Guide::of(Variant::Full, guide);
                    training_step(&net, &mut optimizer, &input, truth, &LossWeights::default(), guide, group).unwrap()
                })
                .collect();
            let params: Vec<Vec<f32>> = named_parameters(&varmap)
                .iter()
                .map(|(_, v)| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
                .collect();
            (losses, params)
        };
        let (one_losses, one_params) = train(&SingleProcess, 0..3);
        let ranks = ThreadGroup::run(2, |group| train(group, [0..2, 2..3][group.rank()].clone()));
        assert!(ranks[0] == ranks[1], "the ranks hold different losses or parameters");
        let (two_losses, two_params) = &ranks[0];
        for (one, two) in one_losses.iter().zip(two_losses) {
            let pairs = [
                (one.mse, two.mse),
                (one.ssim, two.ssim),
                (one.smooth, two.smooth),
                (one.guide, two.guide),
                (one.total, two.total),
            ];
            for (a, b) in pairs {
                assert!((a - b).abs() <= 1e-5 * a.abs().max(1e-3), "{one:?} vs {two:?}");
            }
        }
        assert!(one_losses[1].guide > 0.0 && one_losses[2].guide == 0.0);
        let largest = one_params.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
        let worst =
            one_params.iter().flatten().zip(two_params.iter().flatten()).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= 1e-2 * largest, "parameters differ by {worst} (largest {largest})");
    }

    #[test]
    fn a_window_is_its_step_and_the_checkpointed_steps_before_it() {
        let config = TrainConfig { steps: 1100, checkpoint_every: 250, average_checkpoints: 3, ..Default::default() };
        assert_eq!(window_steps(&config, 1000), [500, 750, 1000]);
        assert_eq!(window_steps(&config, 1100), [750, 1000, 1100], "the last step, off the grid");
        assert_eq!(window_steps(&config, 250), [250], "no checkpoint before the first");
        assert_eq!(window_steps(&config, 500), [250, 500]);
        assert_eq!(describe_model_steps(&window_steps(&config, 500)), "the mean of the parameters of steps 250, 500");
        let one = TrainConfig { average_checkpoints: 1, ..config };
        assert_eq!(window_steps(&one, 1000), [1000]);
        assert_eq!(describe_model_steps(&window_steps(&one, 1000)), "the parameters of step 1000");
    }

    #[test]
    fn every_rank_validates_the_window_that_rank_zero_reads() {
        use crate::distributed::tests::ThreadGroup;
        let dir = tempfile::tempdir().unwrap();
        let config = TrainConfig { checkpoint_every: 2, average_checkpoints: 3, ..Default::default() };
        let model_config = ModelConfig::new(Variant::Full, 0.125);
        // Steps 2 and 4 on disk, step 6 being trained: three seeds' parameters, so that a mean differs from each.
        let mut current = None;
        for (step, seed) in [(2, 1), (4, 2), (6, 3)] {
            let (_, varmap) = IvpNet::seeded(model_config, seed).unwrap();
            let optimizer = Adam::new(named_parameters(&varmap), AdamConfig::default()).unwrap();
            save_checkpoint(&checkpoint_path(dir.path(), step), &varmap, &model_config, &optimizer, step, "{}")
                .unwrap();
            current = Some(varmap);
        }
        let current = current.unwrap();
        let mean = dir.path().join("mean.safetensors");
        export_model(&window_paths(&config, dir.path(), 6), &mean).unwrap();
        let batch = toy_batch();
        let vectors = |net: &IvpNet| -> Vec<f32> {
            net.forward(&toy_input(&batch)).unwrap().vectors.unwrap().flatten_all().unwrap().to_vec1().unwrap()
        };
        let want = vectors(&load_model(&mean).unwrap().0);
        let last_alone = vectors(&load_model(&checkpoint_path(dir.path(), 6)).unwrap().0);
        assert_ne!(want, last_alone, "the test needs a mean that differs from the last step");

        // Rank 1 sees no run folder: it gets the mean from rank 0.
        let nowhere = dir.path().join("not-here");
        let ranks = ThreadGroup::run(2, |group| {
            let folder = if group.rank() == 0 { dir.path() } else { nowhere.as_path() };
            vectors(&window_network(group, &config, folder, 6, &current, model_config).unwrap())
        });
        assert!(ranks.iter().all(|got| *got == want), "a rank validates another network than the model file's");
        let one = vectors(&window_network(&SingleProcess, &config, dir.path(), 6, &current, model_config).unwrap());
        assert_eq!(one, want);
    }

    #[test]
    fn no_variant_is_guided_by_an_input_it_does_not_read() {
        let (b, h, w) = (1, 16, 16);
        let ramp = |c: usize, scale: f32| {
            tensor((0..b * c * h * w).map(|i| (i % 7) as f32 * scale + 0.5).collect(), (b, c, h, w))
        };
        let mask = tensor((0..h * w).map(|i| f32::from((100..140).contains(&i))).collect(), (b, 1, h, w));
        let depth = (ramp(1, 0.5) * (1.0 - &mask).unwrap()).unwrap();
        let warped = ramp(3, 0.1);
        let step = |variant: Variant, prior: &Tensor| {
            let input =
                NetInput { prior, warped_depth: &depth, mask: &mask, warped: &warped, last: None, last_warped: None };
            let (net, varmap) = IvpNet::seeded(ModelConfig::new(variant, 0.125), 1).unwrap();
            let mut optimizer = Adam::new(named_parameters(&varmap), AdamConfig::default()).unwrap();
            let guide = Guide::of(variant, 1.0);
            training_step(&net, &mut optimizer, &input, &warped, &LossWeights::default(), guide, &SingleProcess)
                .unwrap()
        };
        let (prior, other_prior) = (ramp(2, 1.0), ramp(2, -3.0));
        assert_eq!(GuideSource::of(Variant::Intensity), None);
        for variant in [Variant::Full, Variant::NoDepth, Variant::NoTemporalPrior] {
            let (one, two) = (step(variant, &prior), step(variant, &other_prior));
            assert!(one.guide > 0.0, "{variant}: guide {}", one.guide);
            // The prior reaches the guide term (through the vectors, or the target) exactly when
            // the variant reads it.
            let prior_moves_guide = one.guide != two.guide;
            assert_eq!(prior_moves_guide, variant.reads_temporal_prior(), "{variant}: {one:?} vs {two:?}");
            if !variant.reads_temporal_prior() {
                assert_eq!(one, two, "{variant} must not see the prior at all");
            }
        }
        assert_eq!(GuideSource::of(Variant::NoTemporalPrior), Some(GuideSource::DepthFill));
        assert_eq!(GuideSource::of(Variant::Full), Some(GuideSource::DepthFill));
        assert_eq!(GuideSource::of(Variant::NoDepth), Some(GuideSource::TemporalPrior));
    }

    #[test]
    fn motion_scales_must_be_positive_and_bounded() {
        let cases: [(&[f64], bool); 7] = [
            (&[1.0], true),
            (&[1.0, 2.0, 4.0], true),
            (&[], false),
            (&[0.0], false),
            (&[1.0, -2.0], false),
            (&[f64::NAN], false),
            (&[f64::INFINITY], false),
        ];
        for (scales, valid) in cases {
            let config = TrainConfig { motion_scales: scales.to_vec(), ..TrainConfig::default() };
            match config.validate() {
                Ok(()) => assert!(valid, "{scales:?} accepted"),
                Err(e) => assert!(!valid && e.to_string().starts_with("motion_scales must be"), "{scales:?}: {e}"),
            }
        }
    }

    #[test]
    fn validation_targets_must_have_three_frames_before_them() {
        let cases: [(&[usize], bool); 5] = [
            (&[3, 4, 5, 6, 7, 8, 9, 10, 11], true),
            (&[6, 8, 10], true),
            (&[], false),
            (&[2, 6], false),
            (&[0], false),
        ];
        for (targets, valid) in cases {
            let config = TrainConfig { validation_targets: targets.to_vec(), ..TrainConfig::default() };
            match config.validate() {
                Ok(()) => assert!(valid, "{targets:?} accepted"),
                Err(e) => {
                    assert!(!valid && e.to_string().starts_with("validation_targets must be"), "{targets:?}: {e}")
                }
            }
        }
    }

    #[test]
    fn the_mse_weight_must_be_a_finite_non_negative_number() {
        for (weight, valid) in
            [(0.0, true), (1.0, true), (10.0, true), (-1.0, false), (f64::NAN, false), (f64::INFINITY, false)]
        {
            let result = TrainConfig { mse_weight: weight, ..TrainConfig::default() }.validate();
            match result {
                Ok(()) => assert!(valid, "mse_weight {weight} accepted"),
                Err(e) => assert!(!valid && e.to_string().starts_with("mse_weight must be"), "{weight}: {e}"),
            }
        }
    }

    #[test]
    fn the_mse_weight_applies_from_its_fraction_of_the_run_on() {
        let paper = LossWeights::default();
        assert_eq!(TrainConfig::default().loss_weights_at(0), paper);
        let config = TrainConfig { steps: 25, mse_weight: 5.0, mse_weight_from: 0.5, ..TrainConfig::default() };
        // From step ceil(0.5 * 25) = 13 on.
        assert_eq!(config.loss_weights_at(12), paper);
        assert_eq!(config.loss_weights_at(13), LossWeights { mse: 5.0, ..paper });
        assert_eq!(config.loss_weights_at(u64::MAX), LossWeights { mse: 5.0, ..paper });
        let from_the_start = TrainConfig { mse_weight_from: 0.0, ..config.clone() };
        assert_eq!(from_the_start.loss_weights_at(0), LossWeights { mse: 5.0, ..paper });
        for (from, valid) in [(0.0, true), (1.0, true), (-0.1, false), (1.5, false), (f64::NAN, false)] {
            match (TrainConfig { mse_weight_from: from, ..config.clone() }).validate() {
                Ok(()) => assert!(valid, "mse_weight_from {from} accepted"),
                Err(e) => assert!(!valid && e.to_string().starts_with("mse_weight_from must be"), "{from}: {e}"),
            }
        }
    }

    #[test]
    fn the_schedule_changes_are_the_recipes_steps_merged_by_step() {
        let recipe = TrainConfig::default();
        assert_eq!(
            recipe.schedule_changes(),
            [(500, "guide term off".to_string()), (2500, "MSE term x10, near columns".to_string())]
        );
        let choosing = TrainConfig { select_from: 0.5, ..recipe.clone() };
        assert_eq!(choosing.schedule_changes()[1].1, "MSE term x10, near columns, model chosen from here");
        // The paper's loss, no columns, a dataset: the guide alone changes.
        let plain = TrainConfig { mse_weight: 1.0, data: Some("clips".into()), ..choosing.clone() };
        let plain = TrainConfig { validation_data: None, ..plain };
        assert_eq!(plain.schedule_changes(), [(500, "guide term off".to_string())]);
        // Changes at the first or the last step are no changes inside the run.
        let edges =
            TrainConfig { guide_steps: 5000, mse_weight_from: 0.0, near_column_probability_from: 1.0, ..choosing };
        assert_eq!(edges.schedule_changes(), [(2500, "model chosen from here".to_string())]);
    }

    #[test]
    fn generated_scenes_hold_near_columns_from_their_fraction_of_the_run_on() {
        let config = TrainConfig { steps: 25, near_column_probability: 0.7, ..TrainConfig::default() };
        // From step ceil(0.5 * 25) = 13 on, and nothing else changes.
        assert_eq!(config.near_columns_start(), 13);
        let before = config.scene_params_at(12);
        assert_eq!(before.near_column_probability, 0.0);
        assert_eq!(config.scene_params_at(13), SceneParams { near_column_probability: 0.7, ..before });
        assert!(config.scenes_change_at(13) && !config.scenes_change_at(12) && !config.scenes_change_at(14));
        let from_the_start = TrainConfig { near_column_probability_from: 0.0, ..config.clone() };
        assert_eq!(from_the_start.scene_params_at(0).near_column_probability, 0.7);
        // Nothing changes without columns or with a dataset.
        assert!(!TrainConfig { near_column_probability: 0.0, ..config.clone() }.scenes_change_at(13));
        assert!(!TrainConfig { data: Some("clips".into()), ..config.clone() }.scenes_change_at(13));
        for (from, valid) in [(0.0, true), (1.0, true), (-0.1, false), (1.5, false), (f64::NAN, false)] {
            match (TrainConfig { near_column_probability_from: from, ..config.clone() }).validate() {
                Ok(()) => assert!(valid, "near_column_probability_from {from} accepted"),
                Err(e) => {
                    assert!(!valid && e.to_string().starts_with("near_column_probability_from must be"), "{from}: {e}")
                }
            }
        }
    }

    #[test]
    fn the_foreground_guard_is_a_finite_non_negative_weight_for_variants_that_read_depth() {
        for (weight, valid) in [(0.0, true), (2.0, true), (-1.0, false), (f64::NAN, false), (f64::INFINITY, false)] {
            match (TrainConfig { foreground_guard: weight, ..TrainConfig::default() }).validate() {
                Ok(()) => assert!(valid, "foreground_guard {weight} accepted"),
                Err(e) => assert!(!valid && e.to_string().starts_with("foreground_guard must be"), "{weight}: {e}"),
            }
        }
        for variant in Variant::ALL {
            let config = TrainConfig { variant, foreground_guard: 1.0, ..TrainConfig::default() };
            let reads_depth = variant.predicts_vectors() && variant.reads_depth();
            assert_eq!(config.validate().is_ok(), reads_depth, "{variant}");
            let unguarded = TrainConfig { foreground_guard: 0.0, ..config };
            assert!(unguarded.validate().is_ok(), "{variant}");
        }
    }

    #[test]
    fn the_foreground_guard_adds_its_term_to_the_loss_and_the_guide_column() {
        let mut batch = toy_batch();
        // The warp leaves no depth in its holes.
        batch[1] = (&batch[1] * batch[2].affine(-1.0, 1.0).unwrap()).unwrap();
        let (input, truth) = (toy_input(&batch), &batch[4]);
        let (net, mut varmap) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        // Vectors about 3 rows up, off the toy batch's rows of holes, onto its random depths.
        varmap.set_one("d9.bias", Tensor::new(&[0f32, -3.0], &candle_core::Device::Cpu).unwrap()).unwrap();
        let params = named_parameters(&varmap);
        let losses = |foreground_guard: f64| {
            let guide = Guide { foreground_guard, ..Guide::NONE };
            batch_gradients(&net, &params, &input, truth, &LossWeights::default(), guide, &SingleProcess).unwrap().0
        };
        let (plain, guarded) = (losses(0.0), losses(2.0));
        let vectors = net.forward(&input).unwrap().vectors.unwrap();
        let guard = GuideTarget::new(GuideSource::DepthFill, &input).unwrap();
        let guard = guard.at_foreground_reads(&vectors, input.warped_depth).unwrap();
        assert!(guard.count > 0.0, "the toy batch has vectors that read the near side");
        let term =
            2.0 * guard.loss(&vectors, LossCounts::of(input.mask).unwrap().pixels).unwrap().to_scalar::<f32>().unwrap();
        assert!(term > 0.0);
        assert_eq!((plain.guide, guarded.guide), (0.0, term));
        assert!((guarded.total - plain.total - term).abs() <= 1e-6 * guarded.total, "{plain:?} {guarded:?} {term}");
    }

    #[test]
    fn scene_probabilities_must_be_probabilities() {
        for (p, valid) in [(0.0, true), (0.5, true), (1.0, true), (1.5, false), (-0.1, false), (f64::NAN, false)] {
            let near = TrainConfig { near_column_probability: p, ..TrainConfig::default() };
            let fine = TrainConfig { fine_texture_probability: p, ..TrainConfig::default() };
            for (config, field) in [(near, "near_column_probability"), (fine, "fine_texture_probability")] {
                match config.validate() {
                    Ok(()) => assert!(valid, "{field} {p} accepted"),
                    Err(e) => assert!(!valid && e.to_string().starts_with(&format!("{field} must be")), "{p}: {e}"),
                }
            }
        }
    }

    #[test]
    fn the_guide_can_be_the_fill_vectors_for_every_vector_variant() {
        let config = |variant: &str, guide: &str| {
            let text = format!("variant = \"{variant}\"\nguide = \"{guide}\"");
            toml::from_str::<TrainConfig>(&text).map_err(|e| e.to_string())
        };
        let config = |variant: &str, guide: &str| config(variant, guide).unwrap();
        assert_eq!(config("full", "auto").guide_source().unwrap(), Some(GuideSource::DepthFill));
        assert_eq!(config("no-depth", "auto").guide_source().unwrap(), Some(GuideSource::TemporalPrior));
        assert_eq!(config("full", "prior").guide_source().unwrap(), Some(GuideSource::TemporalPrior));
        assert_eq!(config("no-depth", "fill").guide_source().unwrap(), Some(GuideSource::DepthFill));
        assert_eq!(config("intensity", "fill").guide_source().unwrap(), None);
        assert_eq!(config("intensity", "prior").guide_source().unwrap(), None);
        let bad = config("no-tg", "prior").validate().unwrap_err().to_string();
        assert!(bad.contains("no-tg does not read the temporal prior"), "{bad}");
        let text = "guide = \"spread\"";
        let bad = toml::from_str::<TrainConfig>(text).unwrap_err().to_string();
        assert!(bad.contains("auto") && bad.contains("fill") && bad.contains("prior"), "{bad}");
        let guide = config("full", "fill").guide_at(0).unwrap();
        assert_eq!(guide, Guide { source: Some(GuideSource::DepthFill), weight: 1.0, foreground_guard: 0.0 });
        // The default recipe's file form is unchanged: `guide` defaults to `auto` when absent.
        let parsed: TrainConfig = toml::from_str("steps = 10").unwrap();
        assert_eq!(parsed.guide, GuideChoice::Auto);
    }

    #[test]
    fn learning_rate_warms_up_then_decays_to_its_floor() {
        let c =
            TrainConfig { steps: 1000, warmup_steps: 100, lr: 1e-3, final_lr_fraction: 0.1, ..TrainConfig::default() };
        assert!((c.lr_at(0) - 1e-5).abs() < 1e-12);
        assert!((c.lr_at(99) - 1e-3).abs() < 1e-12);
        assert!((c.lr_at(100) - 1e-3).abs() < 1e-12);
        assert!((c.lr_at(550) - 0.55e-3).abs() < 1e-9);
        assert!((c.lr_at(1000) - 1e-4).abs() < 1e-12);
        assert!((c.guide_weight_at(0) - 1.0).abs() < 1e-12 && c.guide_weight_at(c.guide_steps) == 0.0);
    }

    #[test]
    fn every_field_of_the_configuration_reads_from_toml() {
        let text = toml::to_string(&TrainConfig::default()).unwrap();
        assert_eq!(toml::from_str::<TrainConfig>(&text).unwrap(), TrainConfig::default());
        let partial: TrainConfig = toml::from_str("steps = 10\nvariant = \"no-tg\"").unwrap();
        assert_eq!(
            (partial.steps, partial.variant.as_str(), partial.batch),
            (10, "no-tg", TrainConfig::default().batch)
        );
        assert!(toml::from_str::<TrainConfig>("stpes = 10").is_err(), "a misspelt field is an error");
        assert!(toml::from_str::<TrainConfig>("variant = \"big\"").is_err(), "an unknown variant is an error");
    }
}
