//! `ivp bench train|infer|frame`: one training step or one inference timed on random inputs, or
//! one frame end to end on a generated clip.

use anyhow::{ensure, Result};
use clap::Subcommand;

use std::path::PathBuf;

use crate::bench::{bench_infer, bench_train, InferCase, TrainCase};
use crate::bench_frame::{bench_frame, FrameCase};
use crate::checkpoint::check_depth_head_mult;
use crate::cli::CoverageArgs;

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
    /// One frame end to end on a generated clip: warp, holes, prior, network, infill, by stage,
    /// with the hole fraction, the tiles run, and the frame's D-MSE beside fill's.
    Frame(FrameArgs),
}

/// The arguments of `ivp bench frame`.
#[derive(Debug, clap::Args)]
pub struct FrameArgs {
    /// Frame height in pixels.
    #[arg(long, default_value_t = 1080)]
    pub height: usize,
    /// Frame width in pixels.
    #[arg(long, default_value_t = 1920)]
    pub width: usize,
    /// A trained model file; without it, an untrained network of --width-mult.
    #[arg(long, conflicts_with = "width_mult")]
    pub model: Option<PathBuf>,
    /// Width multiplier of the untrained network (the recipe's is 0.25).
    #[arg(long, default_value_t = 0.25)]
    pub width_mult: f64,
    /// Width multiplier of the untrained network's depth head (1 = the paper's).
    #[arg(long, default_value_t = 1.0, conflicts_with = "model")]
    pub depth_head_mult: f64,
    /// Iterations of the test-time infilling (ALGORITHMS.md §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    pub iterations: usize,
    /// Timed runs (after one untimed warm-up run).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Seed of the generated scene.
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
        Ok(FrameCase {
            coverage: self.coverage.coverage()?,
            scale: self.coverage.scale,
            height: self.height,
            width: self.width,
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
            let report = bench_frame(&args.case()?)?;
            println!("{}", serde_json::to_string(&report)?);
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
