//! Project chores: `cargo xtask bench` (criterion benchmarks; with `--torch` ivp's training step and
//! inference against shared/bench/torch_reference.py in the same run; with `--speed-vs-error` time
//! per frame against D-MSE, `speed_vs_error.rs`), and `cargo xtask ablate` (the paper's ablation
//! table over several seeds, `ablate.rs`). Their charts are drawn in `charts.rs`.

use std::path::{Path, PathBuf};
use std::process::Command;

mod ablate;
mod charts;
mod speed_vs_error;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "xtask", about = "ivp's project chores")]
struct Cli {
    #[command(subcommand)]
    command: Task,
}

#[derive(Subcommand)]
enum Task {
    /// The paper's Table 2: intensity, no-tg, no-depth, no-iter (full at P = 1) and full (P = 3),
    /// each trained with every seed on identical data, scored on the Blender clips and a generated
    /// held-out split; mean and spread over seeds in OUT/ablations.{md,csv}. Finished runs are
    /// reused and stopped ones resumed.
    Ablate {
        /// Seeds: each variant is trained once per seed.
        #[arg(long, value_delimiter = ',', default_value = "0,1,2")]
        seeds: Vec<u64>,
        /// Training steps per run (the default recipe's when not given: about 13-19 minutes each on
        /// 2 cores).
        #[arg(long)]
        steps: Option<u64>,
        /// The Blender clips to score on (besides the generated held-out split).
        #[arg(long, default_value = "data/blender-dev")]
        data: PathBuf,
        /// The real clips each run validates on and chooses its model by (the recipe's
        /// `validation_data`): never the clips of --data, which would then score their own choice.
        #[arg(long, default_value = "data/blender-dev-extra")]
        validation_data: PathBuf,
        /// Run folders go to `OUT/<variant>/seed<k>`, the tables to `OUT/ablations.{md,csv}`.
        #[arg(long, default_value = "runs/ablate")]
        out: PathBuf,
        /// A smoke test of the whole pipeline: 4 steps of a tiny network, tiny held-out clips,
        /// the debug build of ivp (under 3 minutes).
        #[arg(long)]
        quick: bool,
        /// Use this ivp binary instead of building one: a sweep that spans code changes keeps
        /// the binary it started with.
        #[arg(long)]
        ivp: Option<PathBuf>,
        /// Also write an HTML report (`ivp eval --report`) of every variant's first seed beside
        /// fill and telea on the Blender clips (the generated split without them) to OUT/report.
        #[arg(long)]
        report: bool,
    },
    /// Run the criterion benchmarks (warping a 1920x1080 frame, convolutions, training samples).
    Bench {
        /// Only benchmarks whose name contains this.
        filter: Option<String>,
        /// Instead of the criterion benchmarks: time `ivp bench train` and `ivp bench infer`
        /// against the PyTorch reference (python3 with torch) one after the other, and print
        /// both figures and their ratio.
        #[arg(long)]
        torch: bool,
        /// Threads of ivp (and of the PyTorch reference, whose default is 2).
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Runs of the training step (inference runs 3 times).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        #[command(flatten)]
        speed: SpeedArgs,
    },
}

/// `cargo xtask bench --speed-vs-error`.
#[derive(clap::Args)]
struct SpeedArgs {
    /// Instead of the criterion benchmarks: time per frame against D-MSE of copy, warp, fill,
    /// oracle, telea and the trained models (P = 1, 2, 3, sparse and dense) with `ivp eval` at
    /// 320x240 and 1920x1080, written to OUT/speed_vs_error.{csv,md,svg} with the Pareto front.
    #[arg(long)]
    speed_vs_error: bool,
    /// Trained models, WIDTH=FILE (those whose file is missing are skipped, with a warning).
    /// By default the committed models: width 0.25 from results/ablate/full/seed0, the others
    /// from results/width/wW (`ivp train --synthetic --width-mult W --depth-head-mult 1 --out
    /// results/width/wW` today: they have the paper's depth head).
    #[arg(long, value_delimiter = ',', default_values_t = speed_vs_error::default_models())]
    models: Vec<String>,
    /// The 320x240 clips (generated clips stand in when the folder is missing).
    #[arg(long, default_value = "data/blender-dev")]
    data: PathBuf,
    /// The 1920x1080 Blender clip, scored besides a generated 1920x1080 clip when it exists.
    #[arg(long, default_value = "../shared/data/blender-dev-hd")]
    data_hd: PathBuf,
    /// Folder of the report.
    #[arg(long, default_value = "results")]
    out: PathBuf,
    /// Folder of the generated clips, scores and the quick model (reused from one run to the next).
    #[arg(long, default_value = "target/speed-vs-error")]
    work: PathBuf,
    /// A test of the pipeline: tiny generated clips, a model trained for 4 steps, the dev build
    /// of ivp; the report goes to target/speed-vs-error-quick unless --out is given.
    #[arg(long)]
    quick: bool,
    /// Use this ivp binary instead of building one.
    #[arg(long)]
    ivp: Option<PathBuf>,
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Task::Ablate { seeds, steps, data, validation_data, out, quick, ivp, report } => {
            ablate::check_seeds(&seeds)?;
            let ivp = match ivp {
                Some(path) if path.is_file() => path,
                Some(path) => bail!("--ivp {}: no such file", path.display()),
                None if quick => build_ivp_debug(&root())?,
                None => build_ivp(&root())?,
            };
            let out = if quick && out == Path::new("runs/ablate") { PathBuf::from("runs/ablate-quick") } else { out };
            let sweep = ablate::Sweep { seeds, steps, blender: data, validation_data, out, quick, report };
            ablate::ablate(&ivp, &sweep)
        }
        Task::Bench { threads, speed, .. } if speed.speed_vs_error => bench_speed_vs_error(threads, speed),
        Task::Bench { torch: true, threads, runs, .. } => bench_against_torch(threads, runs),
        Task::Bench { filter, .. } => bench(filter.as_deref()),
    }
}

fn bench_speed_vs_error(threads: usize, args: SpeedArgs) -> Result<()> {
    let ivp = match args.ivp {
        Some(path) if path.is_file() => path,
        Some(path) => bail!("--ivp {}: no such file", path.display()),
        None if args.quick => build_ivp_debug(&root())?,
        None => build_ivp(&root())?,
    };
    // A quick run must not overwrite the committed report, nor reuse the real run's clips.
    let (out, work) = if args.quick {
        let out =
            if args.out == Path::new("results") { PathBuf::from("target/speed-vs-error-quick") } else { args.out };
        (out.clone(), out.join("work"))
    } else {
        (args.out, args.work)
    };
    let options = speed_vs_error::Options {
        models: speed_vs_error::parse_models(&args.models)?,
        data: args.data,
        data_hd: args.data_hd,
        out,
        work,
        threads,
        quick: args.quick,
        command: typed_command(),
    };
    speed_vs_error::speed_vs_error(&ivp, &options)
}

/// The command as typed (`cargo xtask` and this program's arguments), for reports.
fn typed_command() -> String {
    let args = std::env::args().skip(1).map(|a| {
        if a.is_empty() || a.contains(|c: char| c.is_whitespace() || "'\"$`".contains(c)) {
            format!("'{}'", a.replace('\'', "'\\''"))
        } else {
            a
        }
    });
    std::iter::once("cargo xtask".to_string()).chain(args).collect::<Vec<_>>().join(" ")
}

fn bench(filter: Option<&str>) -> Result<()> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["bench", "-p", "ivp-core", "-p", "ivp-data"]);
    if let Some(f) = filter {
        cmd.args(["--", f]);
    }
    let status = cmd.status().context("running cargo bench")?;
    if !status.success() {
        bail!("cargo bench failed: {status}");
    }
    Ok(())
}

/// The workspace root (xtask lives one level below it).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("xtask is inside the workspace").to_path_buf()
}

/// Runs a command that prints one JSON line last, and returns that line parsed.
fn json_line(cmd: &mut Command) -> Result<serde_json::Value> {
    let output = cmd.output().with_context(|| format!("running {cmd:?}"))?;
    if !output.status.success() {
        bail!("{cmd:?} failed: {}", String::from_utf8_lossy(&output.stderr));
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let line = stdout.lines().last().context("no output")?;
    serde_json::from_str(line).with_context(|| format!("not a JSON line: {line}"))
}

fn bench_against_torch(threads: usize, runs: usize) -> Result<()> {
    let root = root();
    let ivp = build_ivp(&root)?;
    let reference = root.join("../shared/bench/torch_reference.py");
    if !reference.is_file() {
        bail!("{} is missing", reference.display());
    }
    let threads_arg = threads.to_string();
    let runs_arg = runs.to_string();
    let cases: [(&str, Vec<&str>); 2] =
        [("train", vec!["train", "--runs", &runs_arg]), ("infer", vec!["infer", "--runs", "3"])];
    println!("| case | ivp median ms | PyTorch median ms | ivp / PyTorch |");
    println!("|---|---|---|---|");
    let mut machine = None;
    for (name, args) in cases {
        let ours =
            json_line(Command::new(&ivp).args(["--threads", &threads_arg, "bench"]).args(&args).arg("--profile"))?;
        let theirs = json_line(Command::new("python3").arg(&reference).args(&args).args(["--threads", &threads_arg]))?;
        let (a, b) = (ours["median_ms"].as_f64().unwrap_or(f64::NAN), theirs["median_ms"].as_f64().unwrap_or(f64::NAN));
        println!("| {} | {a:.0} | {b:.0} | {:.2} |", theirs["case"].as_str().unwrap_or(name), a / b);
        eprintln!("{name}: ivp {ours}");
        eprintln!("{name}: torch {theirs}");
        machine = Some(machine_named_in(&ours));
    }
    // The ratio is what transfers between machines; the times hold for this CPU only.
    println!("\n{threads} threads on {}", machine.unwrap_or_default());
    Ok(())
}

/// The machine a JSON report of `ivp` (bench or eval) names: `AMD EPYC (avx2)`.
fn machine_named_in(report: &serde_json::Value) -> String {
    let text = |key: &str| report["machine"][key].as_str().unwrap_or("unknown").to_string();
    format!("{} ({})", text("cpu"), text("vectors"))
}

/// Builds the `ivp` binary in release and returns its path.
fn build_ivp(root: &Path) -> Result<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(&cargo)
        .current_dir(root)
        .args(["build", "--release", "-p", "ivp-train"])
        .status()
        .context("building ivp")?;
    if !status.success() {
        bail!("cargo build failed");
    }
    Ok(target_dir(root).join("release/ivp"))
}

/// Builds the `ivp` binary in the dev profile (what the tests already built) and returns its path.
/// It is built as `cargo test --workspace` builds it, beside every test target: a build of the
/// binary alone resolves features without the tests' dev-dependencies, so the day one of them
/// enables a feature of a shared crate it would recompile candle and the ivp crates (90 s).
fn build_ivp_debug(root: &Path) -> Result<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    run(Command::new(cargo).current_dir(root).args(["build", "--workspace", "--tests"]))?;
    Ok(target_dir(root).join("debug/ivp"))
}

/// Where cargo puts what it builds: `CARGO_TARGET_DIR` (relative to the workspace) when set.
fn target_dir(root: &Path) -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), |dir| root.join(dir))
}

fn run(cmd: &mut Command) -> Result<()> {
    let status = cmd.status().with_context(|| format!("running {cmd:?}"))?;
    if !status.success() {
        bail!("{cmd:?} failed: {status}");
    }
    Ok(())
}
