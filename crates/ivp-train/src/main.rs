//! `ivp`: the command-line program. A thin layer over ivp-core, ivp-data and ivp-train.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use ivp_core::inference::ModelInfiller;
use ivp_core::infill::Infiller;
use ivp_core::infill::{classical_infiller, fill_new_regions, CLASSICAL_METHODS};
use ivp_data::{find_clips, write_depth_exr, write_gray_png, write_rgb_png, Clip};
use ivp_train::check::check_clip;
use ivp_train::checkpoint::load_model;
use ivp_train::eval::{
    self, check_targets, clip_name, evaluate, format_table, warp_to_target, Method, DEFAULT_TARGETS,
};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// `mi_option_purge_delay` in mimalloc 3's option enum (libmimalloc-sys names no constant for it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Keeps freed memory mapped instead of handing it back to the OS a moment later. A 1080p
/// inference allocates and frees about 2 GB of feature maps a pass, and on a VM the page faults
/// of mapping them again cost more than the convolutions (1080p inference 14.3 s -> 5.9 s, a
/// 256x256 training step 3.9 s -> 2.7 s); the resident size stays at the peak either way.
fn keep_freed_memory_mapped() {
    // SAFETY: called first thing in `main`, before any other thread exists (the option setter is
    // not thread-safe).
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) }
}

#[derive(Parser)]
#[command(
    name = "ivp",
    version,
    about = "Infilling vector prediction: warp rendered frames to new poses and fill the disocclusions"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Hide progress bars.
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Log more (repeat for more detail); RUST_LOG overrides.
    #[arg(long, short, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Warp one frame into another frame's view, or export the warped targets of a dataset.
    Warp(WarpArgs),
    /// Score infilling methods on every clip of a dataset (SPEC §7 metrics).
    Eval(EvalArgs),
    /// Validate a clip and diagnose convention mistakes (pose direction, axes, depth units).
    Check(CheckArgs),
    /// Render procedural clips (rooms, objects, head-mounted-display camera paths) to disk.
    Generate(GenerateArgs),
    /// Draw one training sample as a labelled sheet (frames, warps, holes, prior, depth).
    ShowSample(ShowSampleArgs),
    /// A short demonstration: train a small network on generated scenes for a few minutes, then
    /// score it against copy, warp and fill.
    Demo(DemoArgs),
    /// Train a network from scratch (or resume a run) on generated scenes or a dataset.
    Train(TrainArgs),
    /// Write the model file (weights and configuration) of a training checkpoint.
    Export(ExportArgs),
    /// Predict one target frame of a clip with a trained model and write images of the result.
    Infer(InferArgs),
    /// Double a clip's frame rate: the even frames are rendered, the odd ones predicted.
    Upsample(UpsampleArgs),
    /// Time one training step or one inference on random inputs (the cases of
    /// shared/bench/torch_reference.py, with the same JSON keys).
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Args)]
struct DemoArgs {
    /// The run folder (run again to reuse the trained model and print the table again).
    #[arg(long, default_value = "runs/demo")]
    out: PathBuf,
    /// Training steps (about 0.2 s each on 2 cores).
    #[arg(long, default_value_t = 1000)]
    steps: u64,
    /// Clips to evaluate on; by default ../shared/data/blender-dev when it exists, otherwise
    /// generated clips the network never saw.
    #[arg(long)]
    data: Option<PathBuf>,
}

#[derive(Args)]
struct TrainArgs {
    /// Train on generated scenes (the default when --data is not given).
    #[arg(long, conflicts_with = "data")]
    synthetic: bool,
    /// Train on the clips of this dataset folder.
    #[arg(long)]
    data: Option<PathBuf>,
    /// A TOML file of training settings (any of the fields of `TrainConfig`); flags override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// full, intensity, no-tg (zeros for the temporal prior) or no-depth (no depth head).
    #[arg(long)]
    variant: Option<String>,
    /// Width multiplier of the U-Net: 1 = the paper's widths (64 ... 256); recipe: 0.25.
    #[arg(long)]
    width_mult: Option<f64>,
    /// Training steps (recipe: 5000, about 21 minutes on 2 cores).
    #[arg(long)]
    steps: Option<u64>,
    /// Crops per step (recipe: 16).
    #[arg(long)]
    batch: Option<usize>,
    /// Side of the square training crops, centred on a disocclusion (recipe: 64).
    #[arg(long)]
    crop: Option<usize>,
    /// Peak learning rate of Adam, after a warm-up and before a cosine decay (recipe: 1e-3).
    #[arg(long)]
    lr: Option<f64>,
    /// Seed of the data and of the initial weights: the same seed gives the same run (recipe: 0).
    #[arg(long)]
    seed: Option<u64>,
    /// Steps between checkpoints.
    #[arg(long)]
    checkpoint_every: Option<u64>,
    /// Steps between validations (0: only at the end).
    #[arg(long)]
    validate_every: Option<u64>,
    /// The run folder: config.toml, metrics.csv, loss.png, checkpoints/, model.safetensors.
    #[arg(long)]
    out: PathBuf,
    /// Continue the run in --out from its last checkpoint (bit-identical to an uninterrupted run).
    #[arg(long)]
    resume: bool,
    /// Stop after this step with a checkpoint, as Ctrl-C does; continue later with --resume.
    #[arg(long)]
    stop_at: Option<u64>,
}

#[derive(Args)]
struct ExportArgs {
    /// A checkpoint (RUN_DIR/checkpoints/step_*.safetensors) or a model file.
    #[arg(long)]
    checkpoint: PathBuf,
    /// The model file to write.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct InferArgs {
    /// The clip folder.
    #[arg(long)]
    clip: PathBuf,
    /// A model file (ivp train writes RUN_DIR/model.safetensors).
    #[arg(long)]
    model: PathBuf,
    /// The frame to predict (from frames T-1 and T-3).
    #[arg(long)]
    target: usize,
    /// Iterations of the test-time infilling (SPEC §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    iterations: usize,
    /// Output folder: infilled.png, holes.png, vectors.png, error.png.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct UpsampleArgs {
    /// The clip folder; its even frames are taken as rendered.
    #[arg(long)]
    clip: PathBuf,
    /// A model file (ivp train writes RUN_DIR/model.safetensors).
    #[arg(long)]
    model: PathBuf,
    /// Iterations of the test-time infilling (SPEC §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    iterations: usize,
    /// Output folder: frames/NNNN.png and preview.gif.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Subcommand)]
enum BenchCommand {
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
}

#[derive(Args)]
struct WarpArgs {
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
    /// Write OUT/<clip name>/<t:04>.png and <t:04>_holes.png for every evaluation target t
    /// (frame t-1 warped to t), so another tool can infill the very same disocclusions.
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
struct EvalArgs {
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
    /// Iterations of the models' test-time infilling (SPEC §6.5).
    #[arg(long, default_value_t = ivp_core::infill::DEFAULT_ITERATIONS)]
    iterations: usize,
    /// Score frames predicted by another tool: NAME=DIR, read from DIR/<clip name>/<t:04>.png.
    #[arg(long, value_name = "NAME=DIR")]
    external: Vec<String>,
}

#[derive(Args)]
struct GenerateArgs {
    /// Output folder: clips are written to OUT/clip_0000, OUT/clip_0001, ... (SPEC §3 layout).
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
}

#[derive(Args)]
struct ShowSampleArgs {
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

#[derive(Args)]
struct CheckArgs {
    /// The clip folder to check.
    #[arg(long)]
    clip: PathBuf,
}

fn main() -> Result<()> {
    keep_freed_memory_mapped();
    let cli = Cli::parse();
    init_logging(cli.verbose);
    if let Some(n) = cli.threads {
        anyhow::ensure!(n > 0, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("setting up the thread pool")?;
    }
    let progress = !cli.quiet;
    match cli.command {
        Command::Warp(args) => run_warp(args, progress),
        Command::Eval(args) => run_eval(args, progress),
        Command::Check(args) => run_check(args),
        Command::Generate(args) => run_generate(args, progress),
        Command::ShowSample(args) => run_show_sample(args),
        Command::Bench(args) => run_bench(args),
        Command::Demo(args) => run_demo(args, progress),
        Command::Train(args) => run_train(args, progress),
        Command::Export(args) => run_export(args),
        Command::Infer(args) => run_infer(args),
        Command::Upsample(args) => run_upsample(args, progress),
    }
}

fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
}

fn run_warp(args: WarpArgs, progress: bool) -> Result<()> {
    if let Some(data) = &args.data {
        return export_targets(data, &args.targets, &args.out, progress);
    }
    let (Some(dir), Some(from), Some(to)) = (&args.clip, args.from, args.to) else {
        bail!("give either --clip DIR --from I --to J, or --data DIR --export-targets");
    };
    let clip = Clip::open(dir)?;
    for i in [from, to] {
        if i >= clip.len() {
            bail!("{}: frame {i} does not exist (the clip has frames 0..={})", dir.display(), clip.len() - 1);
        }
    }
    let frame = clip.load_frame(from)?;
    let transform = ivp_core::relative_pose(clip.pose(from), clip.pose(to));
    let warp = ivp_core::warp_forward(&frame.image, &frame.depth, clip.intrinsics(), &transform);
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    write_warp(&warp, &args.out.join("warped.png"), &args.out.join("holes.png"))?;
    write_depth_exr(args.out.join("depth.exr"), &warp.depth)?;
    let holes = &warp.holes;
    let total = holes.classes().len() as f64;
    println!(
        "warped frame {from} to {to}: {:.2}% disocclusions, {:.2}% new regions -> {}",
        100.0 * holes.count(ivp_core::PixelClass::Disocclusion) as f64 / total,
        100.0 * holes.count(ivp_core::PixelClass::NewRegion) as f64 / total,
        args.out.display()
    );
    Ok(())
}

/// The warped frame with new regions filled by the common rule and disocclusions black, and its holes image.
fn write_warp(warp: &ivp_core::Warp, image_path: &Path, holes_path: &Path) -> Result<()> {
    let mut image = warp.image.clone();
    fill_new_regions(&mut image, &warp.holes);
    write_rgb_png(image_path, &image)?;
    write_gray_png(holes_path, warp.holes.width(), warp.holes.height(), &warp.holes.to_gray8())?;
    Ok(())
}

fn export_targets(data: &Path, targets: &[usize], out: &Path, progress: bool) -> Result<()> {
    let clips: Vec<Clip> = find_clips(data)?.iter().map(Clip::open).collect::<Result<_, _>>()?;
    for clip in &clips {
        check_targets(clip, targets)?;
    }
    let bar = eval::progress_bar(progress, (clips.len() * targets.len()) as u64, "exporting");
    for clip in &clips {
        let name = clip_name(data, clip.path());
        let dir = out.join(&name);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        for &t in targets {
            let warp = warp_to_target(clip, &clip.load_frame(t - 1)?, t);
            write_warp(&warp, &dir.join(format!("{t:04}.png")), &dir.join(format!("{t:04}_holes.png")))?;
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    println!("exported {} targets of {} clips to {}", clips.len() * targets.len(), clips.len(), out.display());
    Ok(())
}

fn parse_methods(args: &EvalArgs) -> Result<Vec<Method>> {
    let mut models = Vec::new();
    for spec in &args.model {
        let (name, file) = match spec.split_once('=') {
            Some((name, file)) => (name.to_string(), PathBuf::from(file)),
            None => ("ivp".to_string(), PathBuf::from(spec)),
        };
        anyhow::ensure!(args.iterations > 0, "--iterations must be at least 1");
        let (net, _) = load_model(&file)?;
        models.push(ModelInfiller::new(name, net, args.iterations));
    }
    let mut methods = Vec::new();
    for name in args.methods.iter().map(|m| m.trim()).filter(|m| !m.is_empty()) {
        if let Some(m) = classical_infiller(name) {
            methods.push(Method::Internal(m));
        } else if let Some(i) = models.iter().position(|m| m.name() == name) {
            methods.push(Method::Internal(Box::new(models.remove(i))));
        } else if name == "ivp" {
            bail!("method `ivp` needs a trained model: add --model FILE");
        } else {
            bail!("unknown method `{name}`: choose among {} or a --model name", CLASSICAL_METHODS.join(", "));
        }
    }
    methods.extend(models.into_iter().map(|m| Method::Internal(Box::new(m))));
    for spec in &args.external {
        let Some((name, dir)) = spec.split_once('=') else {
            bail!("--external takes NAME=DIR, got `{spec}`");
        };
        let dir = PathBuf::from(dir);
        anyhow::ensure!(dir.is_dir(), "--external {name}: {} is not a folder", dir.display());
        methods.push(Method::External { name: name.to_string(), dir });
    }
    let mut names: Vec<&str> = methods.iter().map(|m| m.name()).collect();
    names.sort_unstable();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        bail!("method `{}` is given twice", w[0]);
    }
    Ok(methods)
}

fn run_eval(args: EvalArgs, progress: bool) -> Result<()> {
    let methods = parse_methods(&args)?;
    let report = evaluate(&args.data, &args.targets, &methods, progress)?;
    print!("{}", format_table(&report));
    if let Some(path) = &args.json {
        let json = serde_json::to_string_pretty(&report)?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        ivp_data::write_atomically(path, json.as_bytes())?;
        println!("scores written to {}", path.display());
    }
    Ok(())
}

fn run_train(args: TrainArgs, progress: bool) -> Result<()> {
    use ivp_train::train::{train, RunOptions, TrainConfig};
    let mut config = match &args.config {
        Some(path) => TrainConfig::from_toml_file(path)?,
        None if args.resume => {
            // A resumed run keeps its configuration unless flags change it (only --steps may).
            let path = args.out.join("config.toml");
            TrainConfig::from_toml_file(&path).with_context(|| format!("resuming {}", args.out.display()))?
        }
        None => TrainConfig::default(),
    };
    if args.data.is_some() {
        config.data = args.data.clone();
    }
    if args.synthetic {
        config.data = None;
    }
    macro_rules! set {
        ($($field:ident),*) => {$(if let Some(v) = args.$field.clone() { config.$field = v; })*};
    }
    set!(variant, width_mult, steps, batch, crop, lr, seed, checkpoint_every, validate_every);
    config.validate()?;

    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || {
        if flag.swap(true, std::sync::atomic::Ordering::SeqCst) {
            std::process::exit(130); // a second Ctrl-C: leave at once
        }
        eprintln!("\nCtrl-C: stopping after this step with a checkpoint (press again to quit at once)");
    })
    .context("installing the Ctrl-C handler")?;
    println!(
        "training {} (width {}) on {} for {} steps of {} crops of {}x{} -> {}",
        config.variant,
        config.width_mult,
        config.data.as_ref().map_or("generated scenes".to_string(), |d| d.display().to_string()),
        config.steps,
        config.batch,
        config.crop,
        config.crop,
        args.out.display()
    );
    let options = RunOptions { resume: args.resume, progress, stop: Some(stop), stop_at: args.stop_at };
    let summary = train(&config, &args.out, &options)?;
    let minutes = summary.elapsed.as_secs_f64() / 60.0;
    if let (Some(v), Some(f)) = (summary.last_validation, summary.fill) {
        println!(
            "validation after {} steps ({minutes:.1} min): D-MSE {:.1} D-SSIM {:.4}; fill D-MSE {:.1} D-SSIM {:.4}",
            summary.steps_done, v.d_mse, v.d_ssim, f.d_mse, f.d_ssim
        );
    }
    match &summary.model_path {
        Some(path) => println!("model written to {}", path.display()),
        None => println!("stopped at step {}: continue with --resume", summary.steps_done),
    }
    Ok(())
}

fn run_demo(args: DemoArgs, progress: bool) -> Result<()> {
    use ivp_train::train::{latest_checkpoint, train, RunOptions, TrainConfig};
    let config = TrainConfig { steps: args.steps, ..TrainConfig::demo() };
    let model_path = args.out.join("model.safetensors");
    let resume = latest_checkpoint(&args.out.join("checkpoints"))?.is_some();
    if resume
        && model_path.is_file()
        && ivp_train::checkpoint::load_checkpoint(
            &latest_checkpoint(&args.out.join("checkpoints"))?.expect("checked above"),
        )?
        .step
            >= config.steps
    {
        println!("reusing the model trained in {}", args.out.display());
    } else {
        println!(
            "training a {} network (width {}) on generated scenes: {} steps of {} crops of {}x{} -> {}",
            config.variant,
            config.width_mult,
            config.steps,
            config.batch,
            config.crop,
            config.crop,
            args.out.display()
        );
        let summary = train(&config, &args.out, &RunOptions { resume, progress, ..Default::default() })?;
        println!("trained in {:.1} min", summary.elapsed.as_secs_f64() / 60.0);
    }
    let data = match args.data {
        Some(d) => d,
        None => {
            let shared = PathBuf::from("../shared/data/blender-dev");
            if shared.is_dir() {
                shared
            } else {
                let dir = args.out.join("eval-clips");
                if !dir.is_dir() {
                    let params = ivp_data::SceneParams::default();
                    // A seed far from the training stream's: scenes the network never saw.
                    ivp_data::generate_dataset(&dir, 4, 0xE7A1, &params, |_| {})?;
                }
                dir
            }
        }
    };
    let (net, _) = load_model(&model_path)?;
    let mut methods: Vec<Method> = ["copy", "warp", "fill"]
        .iter()
        .map(|m| Method::Internal(classical_infiller(m).expect("a classical method")))
        .collect();
    methods.push(Method::Internal(Box::new(ModelInfiller::new("ivp", net, ivp_core::infill::DEFAULT_ITERATIONS))));
    println!("evaluating on {}", data.display());
    let report = evaluate(&data, &DEFAULT_TARGETS, &methods, progress)?;
    print!("{}", format_table(&report));
    Ok(())
}

fn run_export(args: ExportArgs) -> Result<()> {
    let config = ivp_train::checkpoint::export_model(&args.checkpoint, &args.out)?;
    println!("exported {} (width {}) to {}", config.variant, config.width_mult, args.out.display());
    Ok(())
}

fn run_infer(args: InferArgs) -> Result<()> {
    anyhow::ensure!(args.iterations > 0, "--iterations must be at least 1");
    let (net, _) = load_model(&args.model)?;
    let model = ModelInfiller::new("ivp", net, args.iterations);
    let clip = Clip::open(&args.clip)?;
    let outputs = ivp_train::infer::run_infer(&model, &clip, args.target, &args.out)?;
    for f in &outputs.files {
        println!("wrote {}", f.display());
    }
    if let Some(mae) = outputs.disocclusion_mae {
        println!("mean absolute error on the disocclusions: {mae:.2} (0..255)");
    }
    Ok(())
}

fn run_upsample(args: UpsampleArgs, progress: bool) -> Result<()> {
    anyhow::ensure!(args.iterations > 0, "--iterations must be at least 1");
    let (net, _) = load_model(&args.model)?;
    let model = ModelInfiller::new("ivp", net, args.iterations);
    let clip = Clip::open(&args.clip)?;
    let bar = eval::progress_bar(progress, clip.len() as u64, "upsampling");
    let summary = ivp_train::infer::run_upsample(&model, &clip, &args.out, |_| bar.inc(1))?;
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

fn run_bench(command: BenchCommand) -> Result<()> {
    use ivp_train::bench::{bench_infer, bench_train, InferCase, TrainCase};
    let check_width = |m: f64| {
        anyhow::ensure!(m > 0.0 && m.is_finite() && m <= 4.0, "--width-mult must be in (0, 4], got {m}");
        Ok(())
    };
    let report = match command {
        BenchCommand::Train { batch, crop, runs, width_mult, profile } => {
            check_width(width_mult)?;
            anyhow::ensure!(batch > 0 && crop >= 16 && runs > 0, "--batch, --runs must be >= 1 and --crop >= 16");
            bench_train(&TrainCase { batch, crop, runs, width_mult, profile })?
        }
        BenchCommand::Infer { height, width, runs, width_mult, profile } => {
            check_width(width_mult)?;
            anyhow::ensure!(height >= 16 && width >= 16 && runs > 0, "--height, --width must be >= 16 and --runs >= 1");
            bench_infer(&InferCase { height, width, runs, width_mult, profile })?
        }
    };
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

fn run_check(args: CheckArgs) -> Result<()> {
    let clip = Clip::open(&args.clip)?;
    println!(
        "{}: {} frames of {}x{}, fx {:.2} fy {:.2} cx {:.2} cy {:.2}",
        args.clip.display(),
        clip.len(),
        clip.width(),
        clip.height(),
        clip.intrinsics().fx,
        clip.intrinsics().fy,
        clip.intrinsics().cx,
        clip.intrinsics().cy
    );
    let report = check_clip(&clip)?;
    println!("warping frames {:?} under each reading (mean absolute error on known pixels, 0..255):", report.pairs);
    for fit in &report.fits {
        println!("  {:>8.2}  {:>5.1}% covered  {}", fit.mae, 100.0 * fit.known_fraction, fit.reading.describe());
    }
    println!("  {:>8.2}  {:>5}          repeating the frame without warping", report.copy_mae, "");
    println!("{}", report.verdict());
    if !report.passes() {
        std::process::exit(1);
    }
    Ok(())
}

fn run_generate(args: GenerateArgs, progress: bool) -> Result<()> {
    anyhow::ensure!(args.clips > 0, "--clips must be at least 1");
    anyhow::ensure!(args.frames >= 2, "--frames must be at least 2");
    anyhow::ensure!(args.width >= 8 && args.height >= 8, "--width and --height must be at least 8");
    anyhow::ensure!(
        args.motion_scale.is_finite() && args.motion_scale >= 0.0,
        "--motion-scale must be a finite number >= 0"
    );
    let params = ivp_data::SceneParams {
        width: args.width,
        height: args.height,
        frames: args.frames,
        motion_scale: args.motion_scale,
        ..Default::default()
    };
    let bar = eval::progress_bar(progress, args.clips as u64, "rendering");
    let dirs = ivp_data::generate_dataset(&args.out, args.clips, args.seed, &params, |_| bar.inc(1))?;
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

fn run_show_sample(args: ShowSampleArgs) -> Result<()> {
    use ivp_data::samples::{ClipSource, DatasetSource, SampleConfig, SampleGenerator, Split, SyntheticSource};
    use ivp_train::sheet::{depth_to_rgb, gray_to_rgb, vectors_to_rgb, Sheet};

    let source: std::sync::Arc<dyn ClipSource> = match &args.data {
        Some(dir) => std::sync::Arc::new(DatasetSource::open(dir)?),
        None => std::sync::Arc::new(SyntheticSource::for_crops_of_256()),
    };
    let config = SampleConfig { seed: args.seed, crop: args.crop, batch_size: args.index + 1, ..Default::default() };
    let generator = SampleGenerator::new(source, config, Split::Train)?;
    let sample = generator.sample(args.step, args.index)?;

    let size = sample.size();
    // 255 on disocclusions, 128 on new regions, 0 on known pixels.
    let holes = ivp_train::validation::hole_mask(&sample).to_gray8();
    let o = &sample.origin;
    let (n2, n, t) = (o.frames.before_last, o.frames.last, o.frames.target);
    let mut sheet = Sheet::new(4);
    sheet
        .add(format!("f{n2}->{n} warped"), sample.last_warped.clone())
        .add(format!("f{n} (last)"), sample.last.clone())
        .add(format!("f{n}->{t} warped"), sample.warped.clone())
        .add(format!("f{t} truth"), sample.truth.clone())
        .add("holes", gray_to_rgb(size, size, &holes))
        .add("prior", vectors_to_rgb(&sample.prior, None))
        .add(format!("depth {t}"), depth_to_rgb(&sample.warped_depth));
    ivp_data::write_rgb_png(&args.out, &sheet.render())?;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The enum index is hard-coded: this fails if a mimalloc upgrade moves `purge_delay`.
    #[test]
    fn the_purge_delay_option_is_the_one_set() {
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
            eprintln!("skipped: MIMALLOC_PURGE_DELAY is set in the environment");
            return;
        }
        // SAFETY: mi_option_get only reads; the test harness may run other tests at the same time,
        // none of which sets options.
        let default = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(default, 1000, "mimalloc 3 purges freed memory after 1000 ms by default");
        keep_freed_memory_mapped();
        assert_eq!(unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) }, -1);
    }
}
