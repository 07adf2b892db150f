//! `ivp warp`, `ivp check`, `ivp generate` and `ivp show-sample`: clips, warps and samples.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, bail, ensure, Result};
use clap::Args;
use ivp_data::samples::{ClipSource, DatasetSource, Sample, SampleConfig, SampleGenerator, Split, SyntheticSource};
use ivp_data::{check_probability, generate_dataset, write_rgb_png, Clip, SceneParams};

use crate::check::{check_clip, CheckReport};
use crate::eval::DEFAULT_TARGETS;
use crate::export_warps::{export_targets, write_frame_pair_warp};
use crate::progress::progress_bar;
use crate::sheet::sample_sheet;

#[derive(Args)]
pub struct WarpArgs {
    /// A clip folder (rgb/, depth/, TransformationMatrices.csv): warp --from into the view of --to.
    #[arg(long, conflicts_with_all = ["data", "export_targets"], requires_all = ["from", "to"])]
    clip: Option<PathBuf>,
    /// Source frame index.
    #[arg(long)]
    from: Option<usize>,
    /// Target frame index.
    #[arg(long)]
    to: Option<usize>,
    /// A dataset folder (clips at any depth); use with --export-targets.
    #[arg(long, requires = "export_targets")]
    data: Option<PathBuf>,
    /// Write OUT/CLIP/TTTT.png and OUT/CLIP/TTTT_holes.png for every evaluation target TTTT
    /// (the frame before it warped to it), so another tool can infill the very same disocclusions.
    #[arg(long, requires = "data")]
    export_targets: bool,
    /// Targets to export (with --export-targets).
    #[arg(long, value_delimiter = ',', default_values_t = DEFAULT_TARGETS)]
    targets: Vec<usize>,
    /// Output folder. Single warp: warped.png (new regions filled by the common rule,
    /// disocclusions black), holes.png (255 disocclusion, 128 new region, 0 known), depth.exr.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
pub struct CheckArgs {
    /// The clip folder to check.
    #[arg(long)]
    clip: PathBuf,
}

#[derive(Args)]
pub struct GenerateArgs {
    /// Output folder: clips are written to OUT/clip_0000, OUT/clip_0001, ... (ALGORITHMS.md §3 layout).
    #[arg(long)]
    out: PathBuf,
    /// Number of clips.
    #[arg(long)]
    clips: usize,
    /// Frames per clip.
    #[arg(long, default_value_t = 12)]
    frames: usize,
    #[arg(long, default_value_t = 320)]
    width: usize,
    #[arg(long, default_value_t = 240)]
    height: usize,
    /// The same seed gives byte-identical files.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Multiplies the camera motion per frame (1: a headset at 30 fps, 1-3 cm and 0.2-0.5 degrees;
    /// larger for low frame rates).
    #[arg(long, default_value_t = 1.0)]
    motion_scale: f64,
    /// Probability that an object near the camera is a floor-to-ceiling column or pole.
    #[arg(long, default_value_t = 0.0)]
    near_column_probability: f64,
    /// Probability that a surface's texture is drawn 2 to 4 times finer than the default patterns.
    #[arg(long, default_value_t = 0.0)]
    fine_texture_probability: f64,
}

#[derive(Args)]
pub struct ShowSampleArgs {
    /// Seed of the sample stream (the same seed, step and index give the same sample).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Training step whose batch the sample belongs to.
    #[arg(long, default_value_t = 0)]
    step: u64,
    /// Index of the sample in its batch.
    #[arg(long, default_value_t = 0)]
    index: usize,
    /// Side of the square crop.
    #[arg(long, default_value_t = 256)]
    crop: usize,
    /// Draw from the clips of this dataset folder instead of generated scenes.
    #[arg(long)]
    data: Option<PathBuf>,
    /// The PNG to write.
    #[arg(long)]
    out: PathBuf,
}

pub fn run_warp(args: WarpArgs, progress: bool) -> Result<()> {
    if let Some(data) = &args.data {
        let exported = export_targets(data, &args.targets, &args.out, progress)?;
        println!("exported {} targets of {} clips to {}", exported.targets, exported.clips, args.out.display());
        return Ok(());
    }
    let (Some(dir), Some(from), Some(to)) = (&args.clip, args.from, args.to) else {
        bail!("give either --clip DIR --from I --to J, or --data DIR --export-targets");
    };
    let holes = write_frame_pair_warp(&Clip::open(dir)?, from, to, &args.out)?;
    println!(
        "warped frame {from} to {to}: {:.2}% disocclusions, {:.2}% new regions -> {}",
        holes.disocclusions,
        holes.new_regions,
        args.out.display()
    );
    Ok(())
}

pub fn run_check(args: CheckArgs) -> Result<()> {
    let clip = match Clip::open(&args.clip) {
        Ok(clip) => clip,
        Err(err) => {
            // An invalid clip (non-rigid pose, implausible intrinsics, frame files) is an answer:
            // name the cause rather than compare readings of files that cannot be right.
            println!("PROBLEM: the clip cannot be read as it is: {err}");
            std::process::exit(1);
        }
    };
    let k = clip.intrinsics();
    println!(
        "{}: {} frames of {}x{}, fx {:.2} fy {:.2} cx {:.2} cy {:.2}",
        args.clip.display(),
        clip.len(),
        clip.width(),
        clip.height(),
        k.fx,
        k.fy,
        k.cx,
        k.cy
    );
    let report = check_clip(&clip)?;
    print_depth_report(&report);
    if report.fits.is_empty() {
        println!("{}", report.verdict());
        std::process::exit(1);
    }
    println!("warping frames {:?} under each reading (mean absolute error on known pixels, 0..255):", report.pairs);
    for fit in &report.fits {
        println!("  {:>8.2}  {:>5.1}% covered  {}", fit.mae, 100.0 * fit.known_fraction, fit.reading.describe());
    }
    println!("  {:>8.2}  {:>5}          repeating the frame without warping", report.copy_mae, "");
    println!("{}", report.verdict());
    if !report.passes() {
        // A failed check is an answer, not an error: the report above says why.
        std::process::exit(1);
    }
    Ok(())
}

/// Depth per frame: one line for the whole clip, then one for each frame with unusable, invalid or
/// implausible values (at most `SHOWN`, the worst cases first in frame order).
fn print_depth_report(report: &CheckReport) {
    const SHOWN: usize = 20;
    println!("depth of {} frames: {}", report.depth.len(), report.total_depth().summary());
    let flagged: Vec<_> = report.depth.iter().filter(|d| !d.stats.is_usable() || d.stats.bad() > 0).collect();
    for d in flagged.iter().take(SHOWN) {
        let label = if !d.stats.is_usable() {
            "NO USABLE DEPTH"
        } else if d.stats.is_suspicious() {
            "suspicious depth"
        } else {
            "some invalid depth"
        };
        println!("  frame {:>4}: {label}: {} ({})", d.frame, d.stats.summary(), d.path.display());
    }
    if flagged.len() > SHOWN {
        println!("  ... and {} more frames with invalid or implausible depth values", flagged.len() - SHOWN);
    }
}

pub fn run_generate(args: GenerateArgs, progress: bool) -> Result<()> {
    ensure!(args.clips > 0, "--clips must be at least 1");
    ensure!(args.frames >= 2, "--frames must be at least 2");
    ensure!(args.width >= 8 && args.height >= 8, "--width and --height must be at least 8");
    ensure!(args.motion_scale.is_finite() && args.motion_scale >= 0.0, "--motion-scale must be a finite number >= 0");
    check_probability(args.near_column_probability)
        .map_err(|problem| anyhow!("--near-column-probability {problem}"))?;
    check_probability(args.fine_texture_probability)
        .map_err(|problem| anyhow!("--fine-texture-probability {problem}"))?;
    let params = SceneParams {
        width: args.width,
        height: args.height,
        frames: args.frames,
        motion_scale: args.motion_scale,
        near_column_probability: args.near_column_probability,
        fine_texture_probability: args.fine_texture_probability,
        ..Default::default()
    };
    let bar = progress_bar(progress, args.clips as u64, "rendering");
    let dirs = generate_dataset(&args.out, args.clips, args.seed, &params, |_| bar.inc(1))?;
    bar.finish_and_clear();
    println!(
        "wrote {} clips of {} frames at {}x{} to {}",
        dirs.len(),
        args.frames,
        args.width,
        args.height,
        args.out.display()
    );
    Ok(())
}

pub fn run_show_sample(args: ShowSampleArgs) -> Result<()> {
    let sample = training_sample(&args)?;
    write_rgb_png(&args.out, &sample_sheet(&sample).render())?;
    let o = &sample.origin;
    let (n2, n, t) = (o.frames.before_last, o.frames.last, o.frames.target);
    println!(
        "sample {} of step {} (seed {}): {}, {:?}, frames {n2}, {n} -> {t}, crop at ({}, {}) -> {}",
        args.index,
        args.step,
        args.seed,
        o.clip_name.display(),
        o.direction,
        o.window.left,
        o.window.top,
        args.out.display()
    );
    Ok(())
}

/// Sample `--index` of the training batch of `--step`, as a run with `--seed` and `--crop` sees it.
fn training_sample(args: &ShowSampleArgs) -> Result<Sample> {
    let source: Arc<dyn ClipSource> = match &args.data {
        Some(dir) => Arc::new(DatasetSource::open(dir)?),
        None => Arc::new(SyntheticSource::for_crops_of_256()),
    };
    let config = SampleConfig { seed: args.seed, crop: args.crop, batch_size: args.index + 1, ..Default::default() };
    let generator = SampleGenerator::new(source, config, Split::Train)?;
    Ok(generator.sample(args.step, args.index)?)
}
