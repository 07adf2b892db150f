//! Crash safety: a training run killed with SIGKILL at random moments and resumed each time ends
//! with the same weights, bit for bit, as a run never interrupted.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ivp_train::train::{checkpoint_step, latest_checkpoint};
use rand::{Rng, SeedableRng};

const RECIPE: &str = "width_mult = 0.125\nsteps = 12\nbatch = 2\ncrop = 32\nguide_steps = 4\n\
                      validation_clips = 1\nvalidation_hd_clips = 0\nlog_every = 1\nvalidate_every = 0\ncheckpoint_every = 2\n";

fn train(config: &Path, out: &Path, resume: bool) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_ivp"));
    cmd.args(["--quiet", "--threads", "2", "train", "--synthetic", "--config"]).arg(config).arg("--out").arg(out);
    if resume {
        cmd.arg("--resume");
    }
    cmd.stdout(Stdio::null()).stderr(Stdio::piped());
    cmd
}

/// The step of the latest complete checkpoint of a run folder (0 without one); a checkpoint being
/// written is a hidden temporary file until its rename.
fn last_checkpoint_step(run: &Path) -> u64 {
    let latest = latest_checkpoint(&run.join("checkpoints")).ok().flatten();
    latest.and_then(|path| checkpoint_step(&path)).unwrap_or(0)
}

/// Every tensor of a model file, by name, as raw bytes.
fn tensors(path: &Path) -> Vec<(String, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut out: Vec<(String, Vec<u8>)> =
        file.tensors().into_iter().map(|(name, view)| (name, view.data().to_vec())).collect();
    out.sort();
    out
}

#[test]
fn a_run_killed_at_random_moments_and_resumed_ends_bit_identical() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("recipe.toml");
    std::fs::write(&config, RECIPE).unwrap();

    let whole = dir.path().join("whole");
    let started = Instant::now();
    let out = train(&config, &whole, false).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let full_time = started.elapsed();

    // Kill each of the first attempts at a random moment shortly after it has saved a checkpoint of
    // its own (its next steps, or the next checkpoint's write), then let the last attempt finish.
    // Waiting for progress rather than for a share of the whole run's time keeps the kills from
    // missing a resumed run, which skips the steps already done and can end before such a share.
    let killed = dir.path().join("killed");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let (mut kills, mut resumes) = (0, 0);
    for attempt in 0.. {
        if killed.join("model.safetensors").is_file() {
            break;
        }
        assert!(attempt < 12, "no run finished after {kills} kills");
        // A kill between a checkpoint's temporary file and its rename leaves only the temporary
        // (hidden: `.name.pid-n.tmp`), which is no checkpoint.
        let has_checkpoint = std::fs::read_dir(killed.join("checkpoints"))
            .is_ok_and(|entries| entries.flatten().any(|e| !e.file_name().to_string_lossy().starts_with('.')));
        if !has_checkpoint {
            // Killed before its first checkpoint: nothing to resume, start again.
            let _ = std::fs::remove_dir_all(&killed);
        }
        resumes += usize::from(has_checkpoint);
        let first_step = last_checkpoint_step(&killed);
        let mut child = train(&config, &killed, has_checkpoint).spawn().unwrap();
        let mut deadline = Instant::now() + Duration::from_secs(600);
        let mut kill_armed = attempt < 6;
        let mut finished = None;
        while Instant::now() < deadline {
            if let Some(status) = child.try_wait().unwrap() {
                finished = Some(status);
                break;
            }
            if kill_armed && last_checkpoint_step(&killed) > first_step {
                kill_armed = false;
                deadline = Instant::now() + full_time.mul_f64(rng.random_range(0.0..0.1));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        match finished {
            Some(status) => {
                let stderr = std::io::read_to_string(child.stderr.take().unwrap()).unwrap();
                assert!(status.success(), "a resumed run failed: {stderr}");
            }
            None => {
                child.kill().unwrap(); // SIGKILL on Unix: no handler runs
                child.wait().unwrap();
                kills += 1;
            }
        }
    }
    eprintln!("{kills} kills, {resumes} resumes from a checkpoint");
    assert!(kills >= 2 && resumes >= 1, "{kills} kills, {resumes} resumes: the test did not interrupt the run");
    assert_eq!(tensors(&killed.join("model.safetensors")), tensors(&whole.join("model.safetensors")));
}
