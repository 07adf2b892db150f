//! `ivp eval`: infilling methods scored on every clip of a dataset.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Args;

use crate::cli::coverage::CoverageArgs;
use crate::eval::{build_methods, evaluate_observed, format_table, write_json, MethodSpecs, DEFAULT_TARGETS};
use crate::report::{
    command_line, describe_machine, prepare_report_dir, write_report, MethodInfo, PageContext, ReportCollector,
    ReportOptions,
};

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
    /// Also write an HTML report into this folder (index.html and its images): the scores, and
    /// per target frame its worst disocclusion regions as every method filled them.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Write the report into a folder that is not empty (files of the same names are replaced).
    #[arg(long, requires = "report")]
    force: bool,
    /// Regions magnified per frame in the report.
    #[arg(long, default_value_t = ReportOptions::default().regions, requires = "report")]
    report_regions: usize,
    #[command(flatten)]
    coverage: CoverageArgs,
}

pub fn run_eval(args: EvalArgs, progress: bool) -> Result<()> {
    let methods = build_methods(&MethodSpecs {
        names: &args.methods,
        models: &args.model,
        iterations: args.iterations,
        rules: args.coverage.rules(),
        externals: &args.external,
        coverage: args.coverage.coverage()?,
        scale: args.coverage.scale,
        prior_scale: args.coverage.prior_scale,
    })?;
    if let Some(dir) = &args.report {
        prepare_report_dir(dir, args.force)?;
    }
    let options = ReportOptions { regions: args.report_regions, ..ReportOptions::default() };
    let mut collector = ReportCollector::new(MethodInfo::of(&methods, &args.model), options);
    let started = Instant::now();
    let report = match &args.report {
        Some(_) => evaluate_observed(&args.data, &args.targets, &methods, progress, &mut collector)?,
        None => evaluate_observed(&args.data, &args.targets, &methods, progress, &mut ())?,
    };
    let seconds = started.elapsed().as_secs_f64();
    print!("{}", format_table(&report));
    if let Some(path) = &args.json {
        write_json(path, &report)?;
        println!("scores written to {}", path.display());
    }
    if let Some(dir) = &args.report {
        let context = PageContext {
            // The program as invoked (target/release/ivp, or ivp on the PATH): the build is part of the times.
            command: command_line(std::env::args()),
            machine: describe_machine(),
            seconds,
            charts: false,
        };
        let written = write_report(dir, &report, &collector, &context)?;
        println!(
            "report written to {} ({} files, {:.2} MB)",
            written.page.display(),
            written.files,
            written.bytes as f64 / 1e6
        );
    }
    Ok(())
}
