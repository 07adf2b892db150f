//! Project chores: `cargo xtask bench` (criterion benchmarks, and with `--torch` ivp's training
//! step and inference against shared/bench/torch_reference.py in the same run), and
//! `cargo xtask ablate` (the paper's ablation table over several seeds, `ablate.rs`).

use std::path::{Path, PathBuf};
use std::process::Command;

mod ablate;

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
        /// Training steps per run (the default recipe's when not given: about 21 minutes each on
        /// 2 cores).
        #[arg(long)]
        steps: Option<u64>,
        /// The Blender clips to score on (besides the generated held-out split).
        #[arg(long, default_value = "../shared/data/blender-dev")]
        data: PathBuf,
        /// Run folders go to OUT/<variant>/seed<k>, the tables to OUT/ablations.{md,csv}.
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
        Task::Ablate { seeds, steps, data, out, quick, ivp } => {
            ablate::check_seeds(&seeds)?;
            let ivp = match ivp {
                Some(path) if path.is_file() => path,
                Some(path) => bail!("--ivp {}: no such file", path.display()),
                None if quick => build_ivp_debug(&root())?,
                None => build_ivp(&root())?,
            };
            let out = if quick && out == Path::new("runs/ablate") { PathBuf::from("runs/ablate-quick") } else { out };
            ablate::ablate(&ivp, &ablate::Sweep { seeds, steps, blender: data, out, quick })
        }
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

/// Builds the `ivp` binary in the dev profile (what the tests already built) and returns its path.
fn build_ivp_debug(root: &Path) -> Result<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    run(Command::new(cargo).current_dir(root).args(["build", "-p", "ivp-train", "--bin", "ivp"]))?;
    Ok(root.join("target/debug/ivp"))
}

fn run(cmd: &mut Command) -> Result<()> {
    let status = cmd.status().with_context(|| format!("running {cmd:?}"))?;
    if !status.success() {
        bail!("{cmd:?} failed: {status}");
    }
    Ok(())
}
