//! The `ivp` command line: the parser of its global options and subcommands, and one file per
//! group of subcommands with their arguments and a thin `run_*` that calls the library and prints.

pub mod bench;
pub mod coverage;
pub mod data;
pub mod eval;
pub mod infer;
pub mod train;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "ivp",
    version,
    about = "Infilling vector prediction: warp rendered frames to new poses and fill the disocclusions"
)]
pub struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    pub threads: Option<usize>,
    /// Hide progress bars.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Log more (repeat for more detail); RUST_LOG overrides.
    #[arg(long, short, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Warp one frame into another frame's view, or export the warped targets of a dataset.
    Warp(data::WarpArgs),
    /// Score infilling methods on every clip of a dataset (ALGORITHMS.md §7 metrics).
    Eval(eval::EvalArgs),
    /// Validate a clip and diagnose convention mistakes (pose direction, axes, depth units).
    Check(data::CheckArgs),
    /// Render procedural clips (rooms, objects, head-mounted-display camera paths) to disk.
    Generate(data::GenerateArgs),
    /// Draw one training sample as a labelled sheet (frames, warps, holes, prior, depth).
    ShowSample(data::ShowSampleArgs),
    /// A short demonstration: train a small network on generated scenes for a few minutes, then
    /// score it against copy, warp and fill.
    Demo(train::DemoArgs),
    /// Train a network from scratch (or resume a run) on generated scenes or a dataset.
    Train(train::TrainArgs),
    /// Write the model file (weights and configuration) of a training checkpoint, or its ONNX graph.
    Export(train::ExportArgs),
    /// Predict one target frame of a clip with a trained model and write images of the result.
    Infer(infer::InferArgs),
    /// Double a clip's frame rate: the even frames are rendered, the odd ones predicted.
    Upsample(infer::UpsampleArgs),
    /// Time one training step or one inference on random inputs (the cases of
    /// shared/bench/torch_reference.py, with the same JSON keys).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}
