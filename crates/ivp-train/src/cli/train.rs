//! `ivp train`, `ivp demo` and `ivp export`: training runs and their model files.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::Args;

use crate::checkpoint::{export_model, load_checkpoint};
use crate::demo::{demo_config, demo_methods, evaluation_data, model_path, plan_training, DemoTraining};
use crate::distributed::{broadcast_from_root, ProcessGroup, SingleProcess};
use crate::eval::{evaluate, format_table, DEFAULT_TARGETS};
use crate::onnx::{export_onnx, OPSET};
use crate::train::{describe_branch, describe_model_steps, train, train_on, RunOptions, TrainConfig, TrainOverrides};

#[derive(Args)]
pub struct TrainArgs {
    /// Train on generated scenes (the default when --data is not given).
    #[arg(long, conflicts_with = "data")]
    synthetic: bool,
    /// Train on the clips of this dataset folder.
    #[arg(long)]
    data: Option<PathBuf>,
    /// A TOML file of training settings (any of the fields of `TrainConfig`); flags override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Settings that override the configuration (the recipe's defaults: `TrainConfig`).
    #[command(flatten)]
    overrides: TrainOverrides,
    /// The run folder: config.toml, metrics.csv, loss.png, checkpoints/, model.safetensors.
    #[arg(long)]
    out: PathBuf,
    /// Continue the run in --out from its last checkpoint (bit-identical to an uninterrupted run).
    #[arg(long)]
    resume: bool,
    /// Stop after this step with a checkpoint, as Ctrl-C does; continue later with --resume.
    #[arg(long)]
    stop_at: Option<u64>,
    /// Start this run from a checkpoint of another run (RUN/checkpoints/step_*.safetensors): its
    /// parameters, optimiser state, step and metrics.csv so far, then this configuration (e.g.
    /// other loss weights for the rest of the run). The network must be the same.
    #[arg(long, value_name = "CHECKPOINT", conflicts_with = "resume")]
    branch_from: Option<PathBuf>,
}

#[derive(Args)]
pub struct DemoArgs {
    /// The run folder (run again to reuse the trained model and print the table again).
    #[arg(long, default_value = "runs/demo")]
    out: PathBuf,
    /// Training steps (about 0.2 s each on 2 cores).
    #[arg(long, default_value_t = 1000)]
    steps: u64,
    /// Clips to evaluate on; by default data/blender-dev (relative to the working folder: the
    /// repository's Blender clips when run from its root), otherwise generated clips the network
    /// never saw.
    #[arg(long)]
    data: Option<PathBuf>,
}

#[derive(Args)]
#[command(group(clap::ArgGroup::new("output").required(true).multiple(true).args(["out", "onnx"])))]
pub struct ExportArgs {
    /// A checkpoint (RUN_DIR/checkpoints/step_*.safetensors) or a model file; with several
    /// (`--checkpoint A B ...`), the parameters of all of them are averaged.
    #[arg(long, required = true, num_args = 1..)]
    checkpoint: Vec<PathBuf>,
    /// The model file (safetensors) to write.
    #[arg(long)]
    out: Option<PathBuf>,
    /// The ONNX graph to write (vector variants: inputs `prior`, `depth`, `hole`; output
    /// `vectors`; opset 17; see MODEL.md).
    #[arg(long)]
    onnx: Option<PathBuf>,
}

/// `ivp train`, in one process or (with the `mpi` feature, under `mpirun` or `srun`) as one rank of
/// a data-parallel job.
pub fn run_train(args: TrainArgs, progress: bool) -> Result<()> {
    #[cfg(feature = "mpi")]
    if let Some(group) = crate::distributed::MpiGroup::join()? {
        group.share_cores_among_local_ranks();
        let result = run_train_on(&group, args, progress);
        if let (Err(e), true) = (&result, group.size() > 1) {
            // The other ranks may be waiting for this one in a collective operation: end the whole
            // job (the launcher names the rank that aborted). Rank 0's last checkpoint stays.
            eprintln!("error on rank {} of {}: {e:#}", group.rank(), group.size());
            group.abort(1);
        }
        return result;
    }
    run_train_on(&SingleProcess, args, progress)
}

fn run_train_on(group: &dyn ProcessGroup, args: TrainArgs, progress: bool) -> Result<()> {
    let is_root = group.rank() == 0;
    // Every rank runs rank 0's configuration: on resume it comes from the run folder, which only
    // rank 0 reads.
    let root_config = is_root.then(|| train_config(&args)).transpose()?;
    let config_json = broadcast_from_root(group, root_config.map(|c| serde_json::to_vec(&c)).transpose()?);
    let config: TrainConfig = serde_json::from_slice(&config_json).context("the configuration from rank 0")?;
    let stop = stop_on_ctrl_c(is_root)?;
    if !is_root {
        let options = RunOptions {
            resume: args.resume,
            branch_from: args.branch_from,
            progress: false,
            stop: Some(stop),
            stop_at: args.stop_at,
        };
        train_on(group, &config, &args.out, &options)?;
        return Ok(());
    }
    let ranks = match group.size() {
        1 => String::new(),
        n => format!(" on {n} ranks"),
    };
    println!(
        "training {} on {} for {} steps of {} crops of {}x{}{ranks} -> {}",
        config.model()?,
        config.data.as_ref().map_or("generated scenes".to_string(), |d| d.display().to_string()),
        config.steps,
        config.batch,
        config.crop,
        config.crop,
        args.out.display()
    );
    if let Some(source) = &args.branch_from {
        println!("{}", describe_branch(&config, source, &load_checkpoint(source)?)?);
    }
    let options = RunOptions {
        resume: args.resume,
        branch_from: args.branch_from,
        progress,
        stop: Some(stop),
        stop_at: args.stop_at,
    };
    let summary = train_on(group, &config, &args.out, &options)?;
    let minutes = summary.elapsed.as_secs_f64() / 60.0;
    if group.size() > 1 {
        let spent = group.time_spent();
        println!(
            "{} ranks, on rank 0: {:.1} ms a step in the gradient all-reduce, {:.1} s in all in the other exchanges \
             (both waiting for slower ranks included)",
            group.size(),
            1e3 * spent.all_reduce.as_secs_f64() / summary.steps_run.max(1) as f64,
            spent.other.as_secs_f64()
        );
    }
    if let (Some(v), Some(f)) = (summary.last_validation, summary.fill) {
        println!("validation after {} steps ({minutes:.1} min): {}", summary.steps_done, v.describe(&f));
    }
    match (&summary.model_path, summary.model_steps.as_slice()) {
        (Some(path), []) => println!("model written to {}", path.display()),
        (Some(path), steps) => println!("model written to {} ({})", path.display(), describe_model_steps(steps)),
        (None, _) => println!("stopped at step {}: continue with --resume", summary.steps_done),
    }
    Ok(())
}

/// The configuration of the run: `--config`, else (on resume) the run's own `config.toml`, else
/// the recipe; then the flags given on top.
fn train_config(args: &TrainArgs) -> Result<TrainConfig> {
    let mut config = match &args.config {
        Some(path) => TrainConfig::from_toml_file(path)?,
        None if args.resume => {
            // A resumed run keeps its configuration unless flags change it (TrainConfig::may_continue).
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
    let config = args.overrides.apply(&config)?;
    config.validate()?;
    Ok(config)
}

/// A flag the first Ctrl-C sets, so that training stops after its step with a checkpoint instead
/// of losing the steps since the last one. With the `mpi` feature SIGTERM sets it too: that is how
/// `mpirun` (on Ctrl-C) and Slurm (`scancel`, the time limit) stop a job. `tell` says so.
fn stop_on_ctrl_c(tell: bool) -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130); // a second Ctrl-C: leave at once
        }
        if tell {
            eprintln!("\nstopping after this step with a checkpoint (Ctrl-C again to quit at once)");
        }
    })
    .context("installing the Ctrl-C handler")?;
    Ok(stop)
}

pub fn run_demo(args: DemoArgs, progress: bool) -> Result<()> {
    let config = demo_config(args.steps);
    match plan_training(&args.out, &config)? {
        DemoTraining::Reuse => println!("reusing the model trained in {}", args.out.display()),
        DemoTraining::Train { resume } => {
            println!(
                "training {} on generated scenes: {} steps of {} crops of {}x{} -> {}",
                config.model()?,
                config.steps,
                config.batch,
                config.crop,
                config.crop,
                args.out.display()
            );
            let summary = train(&config, &args.out, &RunOptions { resume, progress, ..Default::default() })?;
            println!("trained in {:.1} min", summary.elapsed.as_secs_f64() / 60.0);
        }
    }
    let data = evaluation_data(args.data, &args.out)?;
    let methods = demo_methods(&model_path(&args.out))?;
    println!("evaluating on {}", data.display());
    let report = evaluate(&data, &DEFAULT_TARGETS, &methods, progress)?;
    print!("{}", format_table(&report));
    Ok(())
}

pub fn run_export(args: ExportArgs) -> Result<()> {
    let averaged = match args.checkpoint.len() {
        1 => String::new(),
        n => format!(" (the mean of {n} checkpoints)"),
    };
    if let Some(out) = &args.out {
        let config = export_model(&args.checkpoint, out)?;
        println!("exported {config}{averaged} to {}", out.display());
    }
    if let Some(out) = &args.onnx {
        let config = export_onnx(&args.checkpoint, out)?;
        println!("exported {config}{averaged} to {} (ONNX opset {OPSET})", out.display());
    }
    Ok(())
}
