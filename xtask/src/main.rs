//! Project chores: `cargo xtask bench` (criterion benchmarks, and with `--torch` ivp's training
//! step and inference against shared/bench/torch_reference.py in the same run), and
//! `cargo xtask ablate` (train every model variant with one recipe and score them side by side).

use std::path::{Path, PathBuf};
use std::process::Command;

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
    /// Train each model variant with the default recipe (same seed, same data) and evaluate them
    /// beside copy, warp and fill. Runs already trained in OUT are reused, stopped ones resumed.
    Ablate {
        /// Comma-separated variants (full, no-tg, no-depth, intensity).
        #[arg(long, value_delimiter = ',', default_value = "full,no-tg,no-depth,intensity")]
        variants: Vec<String>,
        /// Training steps per variant (the default recipe's when not given: about 21 minutes each
        /// on 2 cores).
        #[arg(long)]
        steps: Option<u64>,
        /// Clips to evaluate on.
        #[arg(long, default_value = "../shared/data/blender-dev")]
        data: PathBuf,
        /// Run folders go to OUT/<variant>; the scores to OUT/scores.json.
        #[arg(long, default_value = "runs/ablate")]
        out: PathBuf,
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
        /// Threads for both (the reference's default is 2).
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Runs of the training step (inference runs 3 times).
        #[arg(long, default_value_t = 5)]
        runs: usize,
    },
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Task::Ablate { variants, steps, data, out } => ablate(&variants, steps, &data, &out),
        Task::Bench { torch: true, threads, runs, .. } => bench_against_torch(threads, runs),
        Task::Bench { filter, .. } => bench(filter.as_deref()),
    }
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
    for (name, args) in cases {
        let ours =
            json_line(Command::new(&ivp).args(["--threads", &threads_arg, "bench"]).args(&args).arg("--profile"))?;
        let theirs = json_line(Command::new("python3").arg(&reference).args(&args).args(["--threads", &threads_arg]))?;
        let (a, b) = (ours["median_ms"].as_f64().unwrap_or(f64::NAN), theirs["median_ms"].as_f64().unwrap_or(f64::NAN));
        println!("| {} | {a:.0} | {b:.0} | {:.2} |", theirs["case"].as_str().unwrap_or(name), a / b);
        eprintln!("{name}: ivp {ours}");
        eprintln!("{name}: torch {theirs}");
    }
    Ok(())
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
    Ok(root.join("target/release/ivp"))
}

fn run(cmd: &mut Command) -> Result<()> {
    let status = cmd.status().with_context(|| format!("running {cmd:?}"))?;
    if !status.success() {
        bail!("{cmd:?} failed: {status}");
    }
    Ok(())
}

fn ablate(variants: &[String], steps: Option<u64>, data: &Path, out: &Path) -> Result<()> {
    let root = root();
    let ivp = build_ivp(&root)?;
    // Paths on the command line are relative to where the user stands, not to the workspace.
    let mut models = Vec::new();
    for variant in variants {
        let dir = out.join(variant);
        let model = dir.join("model.safetensors");
        if model.is_file() {
            println!("{variant}: reusing {}", model.display());
        } else {
            let mut cmd = Command::new(&ivp);
            cmd.args(["train", "--synthetic", "--variant", variant, "--out"]).arg(&dir);
            if let Some(n) = steps {
                cmd.args(["--steps", &n.to_string()]);
            }
            if dir.join("checkpoints").is_dir() {
                cmd.arg("--resume");
            }
            println!("{variant}: training in {}", dir.display());
            run(&mut cmd)?;
        }
        models.push(format!("{variant}={}", model.display()));
    }
    let mut cmd = Command::new(&ivp);
    cmd.args(["eval", "--data"]).arg(data).args(["--methods", "copy,warp,fill"]);
    for m in &models {
        cmd.args(["--model", m]);
    }
    cmd.arg("--json").arg(out.join("scores.json"));
    run(&mut cmd)
}
