//! `ivp bench train|infer|frame`: one training step or one inference timed on random inputs, or
//! one frame end to end on a generated clip.

use anyhow::{ensure, Result};
use clap::Subcommand;

use std::path::PathBuf;

use crate::bench::{bench_infer, bench_train, InferCase, TrainCase};
use crate::bench_frame::{bench_clip, bench_frame, FrameCase, FrameSource};
use crate::checkpoint::check_depth_head_mult;
use crate::cli::coverage::CoverageArgs;
use crate::train::TrainConfig;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Forward, sampler, losses, backward and Adam on one batch.
    Train {
        /// Crops in the batch.
        #[arg(long, default_value_t = 4)]
        batch: usize,
        /// Side of the square crops.
        #[arg(long, default_value_t = 256)]
        crop: usize,
        /// Timed runs (after untimed warm-up runs, as the reference does).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Width multiplier of the U-Net (1 = the paper's widths).
        #[arg(long, default_value_t = 1.0)]
        width_mult: f64,
        /// Add the milliseconds per run spent in each operator.
        #[arg(long)]
        profile: bool,
    },
    /// One dense forward pass and sampling of a frame (padded to a multiple of 16).
    Infer {
        /// Frame height in pixels.
        #[arg(long, default_value_t = 1080)]
        height: usize,
        /// Frame width in pixels.
        #[arg(long, default_value_t = 1920)]
        width: usize,
        /// Timed runs (after untimed warm-up runs, as the reference does).
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Width multiplier of the U-Net (1 = the paper's widths).
        #[arg(long, default_value_t = 1.0)]
        width_mult: f64,
        /// Add the milliseconds per run spent in each operator.
        #[arg(long)]
        profile: bool,
    },
    /// One frame end to end, generated or each target of a clip (--data CLIP --targets ...):
    /// warp, holes, prior, network, infill, by stage, with the hole fraction, the tiles run, the
    /// pixels they read, and the frame's D-MSE beside fill's.
    Frame(FrameArgs),
}

/// The arguments of `ivp bench frame`.
#[derive(Debug, clap::Args)]
pub struct FrameArgs {
    /// Frame height in pixels of the generated frame.
    #[arg(long, default_value_t = 1080, conflicts_with = "data")]
    pub height: usize,
    /// Frame width in pixels of the generated frame.
    #[arg(long, default_value_t = 1920, conflicts_with = "data")]
    pub width: usize,
    /// Time the targets of this clip instead of a generated frame.
    #[arg(long, requires = "targets")]
    pub data: Option<PathBuf>,
    /// The targets of --data to time, comma-separated (each needs frames t-3 .. t).
    #[arg(long, value_delimiter = ',', requires = "data")]
    pub targets: Vec<usize>,
    /// A trained model file; without it, an untrained network of --width-mult.
    #[arg(long, conflicts_with = "width_mult")]
    pub model: Option<PathBuf>,
    /// Width multiplier of the untrained network (default: the recipe's).
    #[arg(long, default_value_t = TrainConfig::default().width_mult)]
    pub width_mult: f64,
    /// Width multiplier of the untrained network's depth head (1 = the paper's; default: the recipe's).
    #[arg(long, default_value_t = TrainConfig::default().depth_head_mult, conflicts_with = "model")]
    pub depth_head_mult: f64,
    /// Iterations of the test-time infilling (ALGORITHMS.md §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    pub iterations: usize,
    /// Timed runs (after one untimed warm-up run).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Seed of the generated scene (and of the untrained network's weights).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub coverage: CoverageArgs,
    /// Add the network's milliseconds per run by operator.
    #[arg(long)]
    pub profile: bool,
}

impl FrameArgs {
    fn case(self) -> Result<FrameCase> {
        ensure_width_mult(self.width_mult)?;
        check_depth_head_mult(self.depth_head_mult).map_err(anyhow::Error::msg)?;
        ensure!(self.height >= 16 && self.width >= 16, "--height and --width must be at least 16");
        let frames = match self.data {
            Some(dir) => FrameSource::Clip { dir, targets: self.targets },
            None => FrameSource::Generated { height: self.height, width: self.width, seed: self.seed },
        };
        Ok(FrameCase {
            coverage: self.coverage.coverage()?,
            scale: self.coverage.scale,
            prior_scale: self.coverage.prior_scale,
            rules: self.coverage.rules(),
            frames,
            model: self.model,
            width_mult: self.width_mult,
            depth_head_mult: self.depth_head_mult,
            iterations: self.iterations,
            runs: self.runs,
            seed: self.seed,
            profile: self.profile,
        })
    }
}

pub fn run_bench(command: BenchCommand) -> Result<()> {
    let report = match command {
        BenchCommand::Train { batch, crop, runs, width_mult, profile } => {
            ensure_width_mult(width_mult)?;
            ensure!(batch > 0 && crop >= 16 && runs > 0, "--batch, --runs must be >= 1 and --crop >= 16");
            bench_train(&TrainCase { batch, crop, runs, width_mult, profile })?
        }
        BenchCommand::Infer { height, width, runs, width_mult, profile } => {
            ensure_width_mult(width_mult)?;
            ensure!(height >= 16 && width >= 16 && runs > 0, "--height, --width must be >= 16 and --runs >= 1");
            bench_infer(&InferCase { height, width, runs, width_mult, profile })?
        }
        BenchCommand::Frame(args) => {
            let case = args.case()?;
            let json = match case.frames {
                FrameSource::Generated { .. } => serde_json::to_string(&bench_frame(&case)?)?,
                FrameSource::Clip { .. } => serde_json::to_string(&bench_clip(&case)?)?,
            };
            println!("{json}");
            return Ok(());
        }
    };
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

fn ensure_width_mult(m: f64) -> Result<()> {
    ensure!(m > 0.0 && m.is_finite() && m <= 4.0, "--width-mult must be in (0, 4], got {m}");
    Ok(())
}
