//! `ivp infer` and `ivp upsample`: a trained model on one target, or on every other frame of a clip.

use std::path::PathBuf;

use anyhow::{ensure, Result};
use clap::Args;
use ivp_core::inference::ModelInfiller;
use ivp_data::Clip;

use crate::checkpoint::load_model;
use crate::cli::coverage::CoverageArgs;
use crate::infer;
use crate::progress::progress_bar;

/// The trained model both commands run, and how.
#[derive(Args)]
pub struct ModelArgs {
    /// A model file (ivp train writes RUN_DIR/model.safetensors).
    #[arg(long)]
    model: PathBuf,
    /// Iterations of the test-time infilling (ALGORITHMS.md §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    iterations: usize,
    #[command(flatten)]
    coverage: CoverageArgs,
}

impl ModelArgs {
    /// The model file as method `ivp`.
    fn infiller(&self) -> Result<ModelInfiller> {
        ensure!(self.iterations > 0, "--iterations must be at least 1");
        let coverage = self.coverage.coverage()?;
        let (net, _) = load_model(&self.model)?;
        Ok(ModelInfiller::new("ivp", net, self.iterations)
            .with_coverage(coverage)
            .with_scale(self.coverage.scale)
            .with_prior_scale(self.coverage.prior_scale)
            .with_rules(self.coverage.rules()))
    }
}

#[derive(Args)]
pub struct InferArgs {
    /// The clip folder.
    #[arg(long)]
    clip: PathBuf,
    /// The frame to predict (from frames T-1 and T-3).
    #[arg(long)]
    target: usize,
    /// Output folder: infilled.png, holes.png, vectors.png, error.png.
    #[arg(long)]
    out: PathBuf,
    /// Also write OUT/network_inputs.safetensors: the inputs of the exported ONNX graph for this
    /// target and what infills and scores from its vectors (MODEL.md, examples/onnx).
    #[arg(long)]
    network_inputs: bool,
    #[command(flatten)]
    model: ModelArgs,
}

#[derive(Args)]
pub struct UpsampleArgs {
    /// The clip folder; its even frames are taken as rendered.
    #[arg(long)]
    clip: PathBuf,
    /// Output folder: frames/NNNN.png and preview.gif.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    model: ModelArgs,
}

pub fn run_infer(args: InferArgs) -> Result<()> {
    let model = args.model.infiller()?;
    let clip = Clip::open(&args.clip)?;
    let outputs = infer::run_infer(&model, &clip, args.target, &args.out)?;
    if args.network_inputs {
        let path = args.out.join("network_inputs.safetensors");
        infer::write_network_inputs(&clip, args.target, &path)?;
        println!("network inputs: {}", path.display());
    }
    for f in &outputs.files {
        println!("wrote {}", f.display());
    }
    if let Some(mae) = outputs.disocclusion_mae {
        println!("mean absolute error on the disocclusions: {mae:.2} (0..255)");
    }
    Ok(())
}

pub fn run_upsample(args: UpsampleArgs, progress: bool) -> Result<()> {
    let model = args.model.infiller()?;
    let clip = Clip::open(&args.clip)?;
    let bar = progress_bar(progress, clip.len() as u64, "upsampling");
    let summary = infer::run_upsample(&model, &clip, &args.out, |_| bar.inc(1))?;
    bar.finish_and_clear();
    println!(
        "{} frames ({} predicted, {:.0} ms each{}) -> {}, preview {}",
        summary.frames,
        summary.predicted,
        summary.ms_per_predicted_frame,
        summary.d_mse.map_or(String::new(), |d| format!(", D-MSE {d:.1}")),
        args.out.join("frames").display(),
        summary.preview.display()
    );
    Ok(())
}
