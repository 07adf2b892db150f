//! Data-parallel training over MPI (feature `mpi`; needs `mpiexec` on the PATH): two ranks with the
//! global batch split between them train like one rank with the whole batch, and a two-rank run
//! stopped by a signal to one of its ranks and resumed ends bit-identical to an uninterrupted one.
//!
//! `cargo test -p ivp-train --features mpi --test mpi`
#![cfg(feature = "mpi")]

use std::collections::HashMap;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A few dozen steps of a small network: the guide fades at step 8, validation at 12 and 24.
const RECIPE: &str = "width_mult = 0.125\nsteps = 24\nbatch = 4\ncrop = 32\nguide_steps = 8\n\
                      validation_clips = 2\nvalidation_hd_clips = 0\nlog_every = 1\nvalidate_every = 12\ncheckpoint_every = 8\n";

/// Tolerances of issue 15's acceptance: logged losses within 1e-3 relative, parameters within 1e-2
/// of the largest parameter. These only say that the run trained alike: 1e-2 is about half of what
/// the warm-up steps can move a parameter, and Adam would hide a gradient scaled by a constant.
/// What data parallelism must get right, the summed gradient of a step against one process's to
/// rounding, with negative controls, is `the_ranks_summed_gradient_is_one_process_gradient_of_the_whole_batch`
/// (src/train.rs); here the ranks run as real MPI processes, with the stop and resume.
const LOSS_TOLERANCE: f64 = 1e-3;
const PARAMETER_TOLERANCE: f64 = 1e-2;

/// `ivp train` on the recipe and the clips in `dir`, by one process (`ranks` 0) or by
/// `mpiexec -n ranks`.
fn train(dir: &Path, out: &str, ranks: usize, extra: &[&str]) -> Command {
    let ivp = env!("CARGO_BIN_EXE_ivp");
    let mut cmd = match ranks {
        0 => Command::new(ivp),
        n => {
            let mut cmd = Command::new("mpiexec");
            cmd.args(["-n", &n.to_string(), ivp]);
            // Open MPI refuses root (CI containers) unless told, and more ranks than cores.
            cmd.envs([
                ("OMPI_ALLOW_RUN_AS_ROOT", "1"),
                ("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1"),
                ("OMPI_MCA_rmaps_base_oversubscribe", "1"),
            ]);
            cmd
        }
    };
    let threads = if ranks == 0 { "2" } else { "1" };
    cmd.args(["--quiet", "--threads", threads, "train", "--data"])
        .arg(dir.join("clips"))
        .arg("--config")
        .arg(dir.join("recipe.toml"))
        .arg("--out")
        .arg(dir.join(out))
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    cmd
}

fn run(mut cmd: Command) -> Output {
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot start {cmd:?} (is MPI installed?): {e}"));
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    assert!(out.status.success(), "{cmd:?} failed:\n{}\n{}", text(&out.stdout), text(&out.stderr));
    out
}

/// Every tensor of a safetensors file, by name, as f32 values.
fn tensors(path: &Path) -> HashMap<String, Vec<f32>> {
    let bytes = std::fs::read(path).unwrap();
    let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let values = |data: &[u8]| data.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    file.tensors().into_iter().map(|(name, view)| (name, values(view.data()))).collect()
}

/// The bits of every value of a model file.
fn bits(path: &Path) -> Vec<(String, Vec<u32>)> {
    let mut all: Vec<_> =
        tensors(path).into_iter().map(|(n, t)| (n, t.iter().map(|v| v.to_bits()).collect())).collect();
    all.sort();
    all
}

/// `metrics.csv` as rows of numbers (empty fields as NaN).
fn metrics(path: &Path) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap_or(f64::NAN)).collect()).collect()
}

/// The children of process `pid` (the ranks that `mpiexec` started on this machine).
fn children(pid: u32) -> Vec<u32> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return Vec::new() };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("children")).ok())
        .flat_map(|s| s.split_whitespace().filter_map(|p| p.parse().ok()).collect::<Vec<u32>>())
        .collect()
}

fn wait_for(child: &mut Child, deadline: Duration) -> Output {
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        assert!(start.elapsed() < deadline, "the job did not end within {deadline:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let (mut stdout, mut stderr) = (String::new(), String::new());
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut stdout).unwrap();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    let status = child.wait().unwrap();
    assert!(status.success(), "the job failed:\n{stdout}\n{stderr}");
    Output { status, stdout: stdout.into_bytes(), stderr: stderr.into_bytes() }
}

#[test]
fn two_ranks_train_like_one_and_resume_bit_identically() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("recipe.toml"), RECIPE).unwrap();
    // A few small clips rendered once, rather than scenes rendered by every run and every rank
    // (training on generated scenes renders 320x240 at least): the test's runs take seconds.
    let mut generate = Command::new(env!("CARGO_BIN_EXE_ivp"));
    generate.args(["--quiet", "generate", "--clips", "3", "--frames", "8", "--width", "160", "--height", "120"]);
    generate.arg("--out").arg(dir.path().join("clips"));
    run(generate);
    run(train(dir.path(), "one", 0, &[]));
    let two = run(train(dir.path(), "two", 2, &[]));
    let said = String::from_utf8_lossy(&two.stdout);
    assert!(said.contains("on 2 ranks") && said.matches("model written").count() == 1, "rank 0 alone reports:\n{said}");

    // The losses logged at every step, and the validation scores, are the global batch's.
    let (one_rows, two_rows) =
        (metrics(&dir.path().join("one/metrics.csv")), metrics(&dir.path().join("two/metrics.csv")));
    assert_eq!(one_rows.len(), 24);
    assert_eq!(one_rows.len(), two_rows.len());
    for (a, b) in one_rows.iter().zip(&two_rows) {
        // step, mse, ssim, smooth, guide, total, val_d_mse, val_d_ssim, fill_d_mse, fill_d_ssim
        for column in 1..10 {
            let (x, y) = (a[column], b[column]);
            if x.is_nan() {
                assert!(y.is_nan(), "step {}: column {column} is {y} with 2 ranks, empty with 1", a[0]);
                continue;
            }
            let tolerance = if column <= 5 { LOSS_TOLERANCE } else { 1e-2 };
            assert!((x - y).abs() <= tolerance * x.abs().max(1e-3), "step {}: column {column}: {x} vs {y}", a[0]);
        }
    }
    let (one, two) =
        (tensors(&dir.path().join("one/model.safetensors")), tensors(&dir.path().join("two/model.safetensors")));
    let largest = one.values().flatten().fold(0f32, |m, v| m.max(v.abs())) as f64;
    let worst = one
        .iter()
        .map(|(name, a)| a.iter().zip(&two[name]).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max))
        .fold(0f32, f32::max) as f64;
    assert!(worst <= PARAMETER_TOLERANCE * largest, "parameters differ by {worst}, the largest is {largest}");
    eprintln!("2 ranks against 1: parameters within {:.2e} of the largest", worst / largest);

    // SIGINT to one rank alone (as Ctrl-C reaching one process): every rank stops after the same
    // step, rank 0 writes a checkpoint there, and the resumed job ends where the whole one did.
    let mut job = train(dir.path(), "stopped", 2, &[]).spawn().unwrap();
    let metrics_csv = dir.path().join("stopped/metrics.csv");
    let start = Instant::now();
    while !metrics_csv.is_file() || metrics(&metrics_csv).len() < 3 {
        assert!(start.elapsed() < Duration::from_secs(300), "no training step logged in 5 minutes");
        std::thread::sleep(Duration::from_millis(10));
    }
    let ranks = children(job.id());
    assert_eq!(ranks.len(), 2, "mpiexec's children: {ranks:?}");
    let status = Command::new("kill").args(["-INT", &ranks[1].to_string()]).status().unwrap();
    assert!(status.success());
    let stopped = wait_for(&mut job, Duration::from_secs(300));
    let said = String::from_utf8_lossy(&stopped.stdout);
    assert!(said.contains("stopped at step"), "the job was not stopped early:\n{said}");
    assert!(!dir.path().join("stopped/model.safetensors").exists());
    run(train(dir.path(), "stopped", 2, &["--resume"]));
    let (whole, resumed) =
        (bits(&dir.path().join("two/model.safetensors")), bits(&dir.path().join("stopped/model.safetensors")));
    assert!(whole == resumed, "the resumed 2-rank run differs from the uninterrupted one");
    let (whole, resumed) =
        (metrics(&dir.path().join("two/metrics.csv")), metrics(&dir.path().join("stopped/metrics.csv")));
    assert_eq!(whole.len(), resumed.len(), "the resumed run logs as many rows as the whole one");
    for (a, b) in whole.iter().zip(&resumed) {
        assert_eq!(
            a[..10].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            b[..10].iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }
}
