//! `ivp demo`: a small network trained on generated scenes for a few minutes, then scored against
//! copy, warp and fill. Running it again on the same folder reuses the trained model.

use std::path::{Path, PathBuf};

use anyhow::Result;
use ivp_core::inference::ModelInfiller;
use ivp_core::infill::{classical_infiller, DEFAULT_ITERATIONS};

use crate::checkpoint::{load_checkpoint, load_model};
use crate::eval::Method;
use crate::train::{latest_checkpoint, TrainConfig};

/// The repository's first four Blender clips (data/README.md), relative to the working folder:
/// what the demo scores on when it runs from the repository's root.
const BLENDER_DEV: &str = "data/blender-dev";

/// Clips generated for scoring when the real ones are missing.
const GENERATED_CLIPS: usize = 4;

/// Far from the training stream's seeds: scenes the network never saw.
const GENERATED_CLIPS_SEED: u64 = 0xE7A1;

/// The demo's training run: the default recipe, shorter.
pub fn demo_config(steps: u64) -> TrainConfig {
    TrainConfig { steps, ..TrainConfig::demo() }
}

/// The model file a finished run leaves in its folder.
pub fn model_path(run_dir: &Path) -> PathBuf {
    run_dir.join("model.safetensors")
}

/// What the demo does before scoring.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DemoTraining {
    /// The run folder holds a model trained for at least the steps asked for.
    Reuse,
    /// Train, continuing the run of the folder when it has a checkpoint.
    Train { resume: bool },
}

/// Reuse the model of `run_dir` when its run got as far as `config` asks, otherwise train (again,
/// or further: a larger step count continues the run).
pub fn plan_training(run_dir: &Path, config: &TrainConfig) -> Result<DemoTraining> {
    let Some(checkpoint) = latest_checkpoint(&run_dir.join("checkpoints"))? else {
        return Ok(DemoTraining::Train { resume: false });
    };
    let finished = model_path(run_dir).is_file() && load_checkpoint(&checkpoint)?.step >= config.steps;
    Ok(if finished { DemoTraining::Reuse } else { DemoTraining::Train { resume: true } })
}

/// The clips to score on: `requested`, else the real clips when they are there (in the working
/// folder: `data/blender-dev`), else clips generated once into the run folder.
pub fn evaluation_data(requested: Option<PathBuf>, run_dir: &Path) -> Result<PathBuf> {
    if let Some(dir) = requested {
        return Ok(dir);
    }
    let blender_dev = PathBuf::from(BLENDER_DEV);
    if blender_dev.is_dir() {
        return Ok(blender_dev);
    }
    let dir = run_dir.join("eval-clips");
    if !dir.is_dir() {
        let params = ivp_data::SceneParams::default();
        ivp_data::generate_dataset(&dir, GENERATED_CLIPS, GENERATED_CLIPS_SEED, &params, |_| {})?;
    }
    Ok(dir)
}

/// copy, warp and fill, then the model of `model_file` as `ivp`.
pub fn demo_methods(model_file: &Path) -> Result<Vec<Method>> {
    let (net, _) = load_model(model_file)?;
    let mut methods: Vec<Method> = ["copy", "warp", "fill"]
        .iter()
        .map(|m| Method::Internal(classical_infiller(m).expect("a classical method")))
        .collect();
    methods.push(Method::Internal(Box::new(ModelInfiller::new("ivp", net, DEFAULT_ITERATIONS))));
    Ok(methods)
}
