//! `ivp eval`: infilling methods scored on every clip of a dataset.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::cli::coverage::CoverageArgs;
use crate::eval::{build_methods, evaluate, format_table, write_json, MethodSpecs, DEFAULT_TARGETS};

#[derive(Args)]
pub struct EvalArgs {
    /// Dataset folder: every clip below it is evaluated (or a single clip folder).
    #[arg(long)]
    data: PathBuf,
    /// Comma-separated methods: copy (the last frame as it is), warp (disocclusions black),
    /// fill (background of the 4 nearest known pixels), oracle (uses the ground truth), telea
    /// (OpenCV's Telea inpainting, radius 5), and the names given with --model (added when not
    /// listed).
    #[arg(long, value_delimiter = ',', default_value = "copy,warp,fill")]
    methods: Vec<String>,
    /// Frames to predict in each clip (each target t is predicted from frames t-3 and t-1).
    #[arg(long, value_delimiter = ',', default_values_t = DEFAULT_TARGETS)]
    targets: Vec<usize>,
    /// Also write the scores as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// A trained model, scored as method `ivp` (FILE) or NAME (NAME=FILE); repeatable.
    #[arg(long, value_name = "[NAME=]FILE")]
    model: Vec<String>,
    /// Iterations of the models' test-time infilling (ALGORITHMS.md §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    iterations: usize,
    /// Score frames predicted by another tool: NAME=DIR, read from DIR/CLIP/TTTT.png (target TTTT of clip CLIP).
    #[arg(long, value_name = "NAME=DIR")]
    external: Vec<String>,
    #[command(flatten)]
    coverage: CoverageArgs,
}

pub fn run_eval(args: EvalArgs, progress: bool) -> Result<()> {
    let methods = build_methods(&MethodSpecs {
        names: &args.methods,
        models: &args.model,
        iterations: args.iterations,
        externals: &args.external,
        coverage: args.coverage.coverage()?,
        scale: args.coverage.scale,
    })?;
    let report = evaluate(&args.data, &args.targets, &methods, progress)?;
    print!("{}", format_table(&report));
    if let Some(path) = &args.json {
        write_json(path, &report)?;
        println!("scores written to {}", path.display());
    }
    Ok(())
}
