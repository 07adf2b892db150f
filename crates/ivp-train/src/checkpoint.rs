//! Model files and training checkpoints, both safetensors.
//!
//! - A **model file** holds only the network's parameters, under the `state_dict` names of
//!   `IvpUNet` in `shared/bench/torch_reference.py`, and the configuration in the safetensors
//!   metadata (`ivp.format`, `ivp.variant`, `ivp.width_mult`, `ivp.depth_head_mult`, `ivp.version`;
//!   files without `ivp.depth_head_mult`, written before it existed, have the paper's depth head).
//!   See MODEL.md.
//! - A **checkpoint** adds Adam's moments (`adam.m.NAME`, `adam.v.NAME`) and, in the metadata, the
//!   step, Adam's step count and the training configuration as JSON: all a bit-identical resume needs
//!   (the samples of a step are a function of the seed and the step alone).
//!
//! Both are written atomically and durably (temporary file flushed to disk, rename, folder
//! flushed): neither a crash nor a power cut leaves half a file or an empty one.
//!
//! Reading refuses what cannot be right before anything is built from it: a width multiplier that
//! is not a multiple of 1/64 in `(0, 4]` ([`check_width_mult`]) or a depth-head multiplier not a
//! multiple of 1/16 ([`check_depth_head_mult`]), encoder widths that differ from
//! the stored tensors' (checked before the network is allocated), and tensors that are not finite
//! (each error names the tensor and the file). Weights loaded to run or export (`load_model`,
//! `export_model`) must also stay within [`MAX_ABS_WEIGHT`].

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use ivp_core::nn::model::{named_parameters, IvpNet, ModelConfig, DEPTH_HEAD_WIDTHS, ENCODER_WIDTHS};
use ivp_core::nn::optim::Adam;

/// Written to `ivp.format`; a file of another format is refused with a clear message.
pub const MODEL_FORMAT: &str = "ivp-model-1";
pub const CHECKPOINT_FORMAT: &str = "ivp-checkpoint-1";

/// Width multipliers are multiples of this: every encoder width (64, 128, 256 times the
/// multiplier) is then a whole number, as `torch_reference.py` builds them.
pub const WIDTH_MULT_STEP: f64 = 1.0 / 64.0;

/// Depth-head multipliers are multiples of this: the depth head's widths (16, 32, 16 times the
/// multiplier) are then whole numbers.
pub const DEPTH_HEAD_MULT_STEP: f64 = 1.0 / 16.0;

/// The largest width multiplier (encoder widths up to 1024), as training and `ivp bench` allow;
/// the depth head's multiplier has the same bound.
pub const MAX_WIDTH_MULT: f64 = 4.0;

/// A parameter beyond this magnitude is not a trained weight: PyTorch's initial bounds are below 1
/// and trained weights of this network stay within about 10.
pub const MAX_ABS_WEIGHT: f32 = 1e6;

/// Why a width multiplier cannot be right, if it cannot: it must be a multiple of
/// [`WIDTH_MULT_STEP`] in `(0, MAX_WIDTH_MULT]`.
pub fn check_width_mult(m: f64) -> Result<(), String> {
    check_multiplier(m, "width multiplier", "encoder widths", &ENCODER_WIDTHS, WIDTH_MULT_STEP, "1/64")
}

/// Why a depth-head multiplier cannot be right, if it cannot: it must be a multiple of
/// [`DEPTH_HEAD_MULT_STEP`] in `(0, MAX_WIDTH_MULT]`.
pub fn check_depth_head_mult(m: f64) -> Result<(), String> {
    check_multiplier(m, "depth-head multiplier", "depth-head widths", &DEPTH_HEAD_WIDTHS, DEPTH_HEAD_MULT_STEP, "1/16")
}

fn check_multiplier(
    m: f64,
    what: &str,
    gives: &str,
    widths: &[usize],
    step: f64,
    step_name: &str,
) -> Result<(), String> {
    let steps = m / step;
    if !(m.is_finite() && m > 0.0 && m <= MAX_WIDTH_MULT) {
        return Err(format!("{what} {m} is out of range: it must be in (0, {MAX_WIDTH_MULT}]"));
    }
    if (steps - steps.round()).abs() > 1e-9 * steps.max(1.0) {
        let widths: Vec<String> = widths.iter().map(|&c| format!("{}", c as f64 * m)).collect();
        return Err(format!(
            "{what} {m} gives {gives} [{}] that are not whole numbers: it must be a multiple of {step_name} ({step})",
            widths.join(", ")
        ));
    }
    Ok(())
}

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{}: {problem}", path.display())]
    Invalid { path: PathBuf, problem: String },
    #[error(transparent)]
    Data(#[from] ivp_data::DataError),
}

fn invalid(path: &Path, problem: impl Into<String>) -> CheckpointError {
    CheckpointError::Invalid { path: path.to_path_buf(), problem: problem.into() }
}

/// A checkpoint as read back.
pub struct Checkpoint {
    pub step: u64,
    pub model: ModelConfig,
    /// The training configuration, as the trainer wrote it (JSON).
    pub train_config: String,
    pub params: HashMap<String, Tensor>,
    pub adam: HashMap<String, Tensor>,
    pub adam_steps: u64,
}

impl Checkpoint {
    /// Puts its parameters into `varmap` and its moments into `optimizer`, as a run resumes,
    /// branches or rolls back from it; `path`, the file it was read from, names it in errors.
    pub fn restore_into(&self, path: &Path, varmap: &VarMap, optimizer: &mut Adam) -> Result<(), CheckpointError> {
        restore_parameters(path, varmap, &self.params)?;
        optimizer.load_state(&self.adam, self.adam_steps).map_err(|e| invalid(path, format!("Adam's state: {e}")))
    }
}

/// Writes the network's parameters and configuration as a model file; `step`, the training step
/// the weights are from, goes to the metadata (`ivp.step`) when known.
pub fn save_model(
    path: &Path,
    varmap: &VarMap,
    config: &ModelConfig,
    step: Option<u64>,
) -> Result<(), CheckpointError> {
    let tensors: Vec<(String, Tensor)> =
        named_parameters(varmap).into_iter().map(|(name, var)| (name, var.as_tensor().clone())).collect();
    write(path, tensors, model_metadata(config, MODEL_FORMAT, step))
}

/// Writes a checkpoint of `step`: parameters, Adam's state and the training configuration.
pub fn save_checkpoint(
    path: &Path,
    varmap: &VarMap,
    config: &ModelConfig,
    optimizer: &Adam,
    step: u64,
    train_config_json: &str,
) -> Result<(), CheckpointError> {
    let mut tensors: Vec<(String, Tensor)> =
        named_parameters(varmap).into_iter().map(|(name, var)| (name, var.as_tensor().clone())).collect();
    let (adam, adam_steps) = optimizer.state();
    let mut adam: Vec<(String, Tensor)> = adam.into_iter().collect();
    adam.sort_by(|a, b| a.0.cmp(&b.0));
    tensors.extend(adam);
    let mut metadata = model_metadata(config, CHECKPOINT_FORMAT, Some(step));
    metadata.insert("ivp.adam_steps".into(), adam_steps.to_string());
    metadata.insert("ivp.train_config".into(), train_config_json.to_string());
    write(path, tensors, metadata)
}

/// Reads a checkpoint, checking that it is one and that it is complete.
pub fn load_checkpoint(path: &Path) -> Result<Checkpoint, CheckpointError> {
    let (tensors, metadata) = read(path, CHECKPOINT_FORMAT)?;
    let model = model_config_from(path, &metadata)?;
    let number = |key: &str| -> Result<u64, CheckpointError> {
        metadata
            .get(key)
            .ok_or_else(|| invalid(path, format!("metadata `{key}` is missing")))?
            .parse()
            .map_err(|_| invalid(path, format!("metadata `{key}` is not a whole number")))
    };
    let (step, adam_steps) = (number("ivp.step")?, number("ivp.adam_steps")?);
    let train_config = metadata.get("ivp.train_config").cloned().unwrap_or_default();
    let (adam, params): (HashMap<_, _>, HashMap<_, _>) = tensors.into_iter().partition(|(k, _)| k.starts_with("adam."));
    Ok(Checkpoint { step, model, train_config, params, adam, adam_steps })
}

/// Writes the model file of a checkpoint (or copies a model file), after checking that its
/// parameters build the network its metadata describes. Several checkpoints (of one network) are
/// averaged parameter by parameter ([`averaged_model`]).
pub fn export_model(checkpoints: &[PathBuf], out: &Path) -> Result<ModelConfig, CheckpointError> {
    let model = averaged_model(checkpoints, out)?;
    write(out, model.parameters, model_metadata(&model.config, MODEL_FORMAT, model.step))?;
    Ok(model.config)
}

/// A model read back for export: its network, configuration, parameters (sorted by name) and the
/// training step they are from, if recorded.
pub struct ExportedModel {
    pub net: IvpNet,
    pub config: ModelConfig,
    pub parameters: Vec<(String, Tensor)>,
    pub step: Option<u64>,
}

impl ExportedModel {
    /// What a model file's metadata says of it (MODEL.md), sorted by key.
    pub fn metadata(&self) -> Vec<(String, String)> {
        let mut metadata: Vec<_> = model_metadata(&self.config, MODEL_FORMAT, self.step).into_iter().collect();
        metadata.sort();
        metadata
    }
}

/// The model of one checkpoint or model file, or the mean of several (of one network), parameter
/// by parameter in the order given: the mean of the weights of the last steps of a run varies less
/// from seed to seed than the last step's (results/recipe-hd/README.md). Every file is checked as
/// [`load_model`] checks it, and so is the mean. `out` names the export in errors.
pub fn averaged_model(checkpoints: &[PathBuf], out: &Path) -> Result<ExportedModel, CheckpointError> {
    let Some((first, rest)) = checkpoints.split_first() else {
        return Err(invalid(out, "no checkpoint to export"));
    };
    let (net, config, first_parameters, mut step) = read_model(first)?;
    if rest.is_empty() {
        let mut parameters: Vec<(String, Tensor)> = first_parameters.into_iter().collect();
        parameters.sort_by(|a, b| a.0.cmp(&b.0));
        return Ok(ExportedModel { net, config, parameters, step });
    }
    let mut sets = vec![first_parameters];
    for path in rest {
        let (_, other, tensors, other_step) = read_model(path)?;
        if other != config {
            return Err(invalid(path, format!("a {other:?} network cannot be averaged with {first:?}'s {config:?}")));
        }
        if let Some(name) = sets[0].keys().find(|name| !tensors.contains_key(*name)) {
            return Err(invalid(path, format!("parameter `{name}` is missing")));
        }
        sets.push(tensors);
        step = step.max(other_step);
    }
    let mean = mean_of(&sets).map_err(|e| invalid(out, e.to_string()))?;
    let net = network_from(out, &mean, config)?.detached();
    let mut parameters: Vec<(String, Tensor)> = mean.into_iter().collect();
    parameters.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(ExportedModel { net, config, parameters, step })
}

/// The mean of sets of the same named parameters (every name of the first in each), added up in
/// the order given and divided by their count: the one place a mean of weights is taken, so that
/// a run's validation of a window and the model file written from it are the same bits.
pub fn mean_of(sets: &[HashMap<String, Tensor>]) -> candle_core::Result<HashMap<String, Tensor>> {
    let count = sets.len() as f64;
    let Some((first, rest)) = sets.split_first() else { return Ok(HashMap::new()) };
    first
        .iter()
        .map(|(name, t)| {
            let mut total = t.clone();
            for set in rest {
                total = total.add(&set[name])?;
            }
            Ok((name.clone(), (total / count)?))
        })
        .collect()
}

/// Reads a model file (or the parameters of a checkpoint) and builds the network for inference
/// (on plain tensors: see [`IvpNet::detached`]).
pub fn load_model(path: &Path) -> Result<(IvpNet, ModelConfig), CheckpointError> {
    let (net, config, _, _) = read_model(path)?;
    Ok((net, config))
}

/// A network, its configuration, its parameters and the training step they are from (if recorded).
type ModelParts = (IvpNet, ModelConfig, HashMap<String, Tensor>, Option<u64>);

fn read_model(path: &Path) -> Result<ModelParts, CheckpointError> {
    let bytes = std::fs::read(path)
        .map_err(|e| CheckpointError::Data(ivp_data::DataError::io(path, "cannot read model file", e)))?;
    let metadata = metadata_of(path, &bytes)?;
    let format = metadata.get("ivp.format").map(String::as_str).unwrap_or("");
    if format != MODEL_FORMAT && format != CHECKPOINT_FORMAT {
        return Err(invalid(path, format!("not an ivp model file (format `{format}`, expected `{MODEL_FORMAT}`)")));
    }
    let config = model_config_from(path, &metadata)?;
    let mut tensors = tensors_of(path, &bytes)?;
    tensors.retain(|name, _| !name.starts_with("adam."));
    // Weights to run or export must also be of a plausible magnitude. (A checkpoint to resume
    // from need only be finite: the training loop's guard reports a run that diverges.)
    let mut names: Vec<&String> = tensors.keys().collect();
    names.sort();
    for name in names {
        check_values(name, &tensors[name], MAX_ABS_WEIGHT).map_err(|problem| invalid(path, problem))?;
    }
    let net = network_from(path, &tensors, config)?.detached();
    let step = metadata.get("ivp.step").and_then(|s| s.parse().ok());
    Ok((net, config, tensors, step))
}

/// Builds a network of `config` from named parameters, checking that every parameter is present
/// with its shape and that nothing is left over (strict, like PyTorch's `load_state_dict`).
pub fn network_from(
    path: &Path,
    tensors: &HashMap<String, Tensor>,
    config: ModelConfig,
) -> Result<IvpNet, CheckpointError> {
    check_encoder_widths(path, tensors, config)?;
    let (net, varmap) = IvpNet::seeded(config, 0).map_err(|e| invalid(path, e.to_string()))?;
    let expected = named_parameters(&varmap);
    for (name, var) in &expected {
        let Some(t) = tensors.get(name) else {
            return Err(invalid(path, format!("parameter `{name}` is missing (a {config:?} network needs it)")));
        };
        if t.dims() != var.dims() {
            return Err(invalid(
                path,
                format!("parameter `{name}` has shape {:?}, expected {:?}", t.dims(), var.dims()),
            ));
        }
        var.set(t).map_err(|e| invalid(path, format!("parameter `{name}`: {e}")))?;
    }
    if let Some(extra) = tensors.keys().find(|k| !expected.iter().any(|(n, _)| n == *k)) {
        return Err(invalid(path, format!("unexpected tensor `{extra}` for a {config:?} network")));
    }
    Ok(net)
}

/// The output widths of `e1 .. e5` as stored must be those of `config`: checked before the network
/// is allocated, so that metadata claiming a huge width cannot make us build it.
fn check_encoder_widths(
    path: &Path,
    tensors: &HashMap<String, Tensor>,
    config: ModelConfig,
) -> Result<(), CheckpointError> {
    let widths = config.encoder_widths();
    for (i, &width) in widths.iter().enumerate() {
        let name = format!("e{}.weight", i + 1);
        let Some(t) = tensors.get(&name) else {
            return Err(invalid(path, format!("parameter `{name}` is missing (a {config:?} network needs it)")));
        };
        if t.dims().first() != Some(&width) {
            return Err(invalid(
                path,
                format!(
                    "parameter `{name}` has shape {:?}, but the metadata (width multiplier {}) gives encoder widths \
                     {widths:?}: the metadata does not match the weights",
                    t.dims(),
                    config.width_mult
                ),
            ));
        }
    }
    Ok(())
}

/// Copies named parameters into the variables of `varmap` (for a resumed run).
pub fn restore_parameters(
    path: &Path,
    varmap: &VarMap,
    tensors: &HashMap<String, Tensor>,
) -> Result<(), CheckpointError> {
    for (name, var) in named_parameters(varmap) {
        let t = tensors.get(&name).ok_or_else(|| invalid(path, format!("parameter `{name}` is missing")))?;
        if t.dims() != var.dims() {
            return Err(invalid(
                path,
                format!("parameter `{name}` has shape {:?}, expected {:?}", t.dims(), var.dims()),
            ));
        }
        var.set(t).map_err(|e| invalid(path, format!("parameter `{name}`: {e}")))?;
    }
    Ok(())
}

/// A network's variables and a builder over them: the trainer's view of a model.
pub fn varbuilder(varmap: &VarMap) -> VarBuilder<'static> {
    VarBuilder::from_varmap(varmap, candle_core::DType::F32, &Device::Cpu)
}

/// The metadata that model files and checkpoints share: format, configuration, version, and the
/// training step of the weights when known.
fn model_metadata(config: &ModelConfig, format: &str, step: Option<u64>) -> HashMap<String, String> {
    let mut metadata = HashMap::from([
        ("ivp.format".to_string(), format.to_string()),
        ("ivp.variant".to_string(), config.variant.as_str().to_string()),
        ("ivp.width_mult".to_string(), config.width_mult.to_string()),
        ("ivp.depth_head_mult".to_string(), config.depth_head_mult.to_string()),
        ("ivp.version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
    ]);
    if let Some(step) = step {
        metadata.insert("ivp.step".to_string(), step.to_string());
    }
    metadata
}

fn model_config_from(path: &Path, metadata: &HashMap<String, String>) -> Result<ModelConfig, CheckpointError> {
    let get = |key: &str| metadata.get(key).ok_or_else(|| invalid(path, format!("metadata `{key}` is missing")));
    let variant = get("ivp.variant")?.parse().map_err(|e: String| invalid(path, e))?;
    let width_mult: f64 =
        get("ivp.width_mult")?.parse().map_err(|_| invalid(path, "metadata `ivp.width_mult` is not a number"))?;
    check_width_mult(width_mult).map_err(|problem| invalid(path, format!("metadata `ivp.width_mult`: {problem}")))?;
    // Files written before the depth head could be scaled have the paper's.
    let depth_head_mult: f64 = match metadata.get("ivp.depth_head_mult") {
        Some(m) => m.parse().map_err(|_| invalid(path, "metadata `ivp.depth_head_mult` is not a number"))?,
        None => 1.0,
    };
    check_depth_head_mult(depth_head_mult)
        .map_err(|problem| invalid(path, format!("metadata `ivp.depth_head_mult`: {problem}")))?;
    Ok(ModelConfig::new(variant, width_mult).with_depth_head_mult(depth_head_mult))
}

fn write(
    path: &Path,
    tensors: Vec<(String, Tensor)>,
    metadata: HashMap<String, String>,
) -> Result<(), CheckpointError> {
    let bytes = safetensors::serialize(tensors, Some(metadata))
        .map_err(|e| invalid(path, format!("cannot serialise tensors: {e}")))?;
    let bytes = with_sorted_header(bytes).map_err(|e| invalid(path, format!("cannot serialise tensors: {e}")))?;
    ivp_data::write_durably(path, &bytes)?;
    Ok(())
}

/// safetensors writes its JSON header in the order of HashMaps, which differs from one map to the
/// next, so the same parameters would give files that differ. The header is written again with
/// every key sorted: the same keys and values in compact JSON, hence the same length, padded with
/// spaces as safetensors pads it.
fn with_sorted_header(mut bytes: Vec<u8>) -> Result<Vec<u8>, String> {
    let length = bytes.get(..8).map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes"))).ok_or("no header")?;
    let end = usize::try_from(length).ok().and_then(|n| n.checked_add(8)).filter(|&end| end <= bytes.len());
    let end = end.ok_or("a header longer than the file")?;
    let mut header: BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..end]).map_err(|e| e.to_string())?;
    if let Some(metadata) = header.get_mut("__metadata__") {
        let sorted: BTreeMap<String, String> = serde_json::from_value(metadata.take()).map_err(|e| e.to_string())?;
        *metadata = serde_json::to_value(sorted).map_err(|e| e.to_string())?;
    }
    let mut json = serde_json::to_vec(&header).map_err(|e| e.to_string())?;
    if json.len() > end - 8 {
        return Err(format!("the sorted header takes {} bytes, not {}", json.len(), end - 8));
    }
    json.resize(end - 8, b' ');
    bytes[8..end].copy_from_slice(&json);
    Ok(bytes)
}

/// Named tensors and the string metadata of a safetensors file.
type TensorsAndMetadata = (HashMap<String, Tensor>, HashMap<String, String>);

fn read(path: &Path, format: &str) -> Result<TensorsAndMetadata, CheckpointError> {
    let bytes =
        std::fs::read(path).map_err(|e| CheckpointError::Data(ivp_data::DataError::io(path, "cannot read", e)))?;
    let metadata = metadata_of(path, &bytes)?;
    let found = metadata.get("ivp.format").map(String::as_str).unwrap_or("");
    if found != format {
        return Err(invalid(path, format!("not an ivp checkpoint (format `{found}`, expected `{format}`)")));
    }
    Ok((tensors_of(path, &bytes)?, metadata))
}

fn metadata_of(path: &Path, bytes: &[u8]) -> Result<HashMap<String, String>, CheckpointError> {
    let (_, metadata) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| invalid(path, format!("not a readable safetensors file (truncated or corrupt?): {e}")))?;
    Ok(metadata.metadata().clone().unwrap_or_default())
}

fn tensors_of(path: &Path, bytes: &[u8]) -> Result<HashMap<String, Tensor>, CheckpointError> {
    // Reads (and so checks) every tensor's data, not only the header.
    let tensors = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)
        .map_err(|e| invalid(path, format!("not a readable safetensors file (truncated or corrupt?): {e}")))?;
    let mut names: Vec<&String> = tensors.keys().collect();
    names.sort();
    for name in names {
        let t = &tensors[name];
        if t.dtype() != candle_core::DType::F32 {
            return Err(invalid(path, format!("tensor `{name}` is {:?}, expected f32", t.dtype())));
        }
        check_values(name, t, f32::MAX).map_err(|problem| invalid(path, problem))?;
    }
    Ok(tensors)
}

/// Why the values of a tensor cannot be weights, if they cannot: not finite, or beyond `bound`.
fn check_values(name: &str, t: &Tensor, bound: f32) -> Result<(), String> {
    let values = t.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(|e| format!("tensor `{name}`: {e}"))?;
    let non_finite = values.iter().filter(|v| !v.is_finite()).count();
    if non_finite > 0 {
        return Err(format!(
            "tensor `{name}` has {non_finite} non-finite values (NaN or infinite) of {}: the weights are broken",
            values.len()
        ));
    }
    if let Some(big) = values.iter().copied().find(|v| v.abs() > bound) {
        return Err(format!(
            "tensor `{name}` holds {big:e}, beyond the plausible magnitude {bound:e} of a weight: the weights are broken"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ivp_core::nn::model::Variant;

    const SMALL: ModelConfig = ModelConfig::new(Variant::Full, 0.125);

    /// A model file of `SMALL`, rewritten with `edit` applied to its tensors and metadata.
    fn model_file(
        dir: &Path,
        edit: impl FnOnce(&mut HashMap<String, Tensor>, &mut HashMap<String, String>),
    ) -> PathBuf {
        let path = dir.join("model.safetensors");
        let (_, varmap) = IvpNet::seeded(SMALL, 3).unwrap();
        save_model(&path, &varmap, &SMALL, Some(7)).unwrap();
        let (mut tensors, mut metadata) = read(&path, MODEL_FORMAT).unwrap();
        edit(&mut tensors, &mut metadata);
        write(&path, tensors.into_iter().collect(), metadata).unwrap();
        path
    }

    fn load_err(path: &Path) -> String {
        let Err(err) = load_model(path) else { panic!("the model file should be refused") };
        let err = err.to_string();
        assert!(err.contains(&path.display().to_string()), "the message does not name the file: {err}");
        err
    }

    #[test]
    fn the_same_parameters_give_the_same_file_bytes() {
        // Metadata comes as a HashMap, whose order changes from one map to the next: written as
        // it comes, two saves of one model differ (tried 8 times, so that luck cannot pass).
        let dir = tempfile::tempdir().unwrap();
        let (_, varmap) = IvpNet::seeded(SMALL, 3).unwrap();
        let first = dir.path().join("first.safetensors");
        save_model(&first, &varmap, &SMALL, Some(7)).unwrap();
        for i in 0..8 {
            let again = dir.path().join(format!("again{i}.safetensors"));
            save_model(&again, &varmap, &SMALL, Some(7)).unwrap();
            assert_eq!(std::fs::read(&first).unwrap(), std::fs::read(&again).unwrap(), "save {i}");
        }
    }

    #[test]
    fn a_sound_model_file_loads() {
        let dir = tempfile::tempdir().unwrap();
        let path = model_file(dir.path(), |_, _| {});
        assert_eq!(load_model(&path).unwrap().1, SMALL);
    }

    #[test]
    fn width_multipliers_must_give_whole_widths() {
        for m in [0.25, 0.125, 1.0, 1.0 / 64.0, 4.0, 0.75] {
            check_width_mult(m).unwrap();
        }
        for m in [0.1, 0.3, 1e9, 4.5, 0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(check_width_mult(m).is_err(), "{m}");
        }
        assert!(check_width_mult(0.1).unwrap_err().contains("not whole numbers"));
    }

    #[test]
    fn depth_head_multipliers_must_give_whole_widths() {
        for m in [1.0, 0.5, 0.25, 1.0 / 16.0, 4.0] {
            check_depth_head_mult(m).unwrap();
        }
        for m in [0.1, 1.0 / 64.0, 4.5, 0.0, f64::NAN] {
            assert!(check_depth_head_mult(m).is_err(), "{m}");
        }
        assert!(check_depth_head_mult(0.1).unwrap_err().contains("depth-head widths"));
    }

    #[test]
    fn files_from_before_the_depth_head_multiplier_have_the_papers_head() {
        let dir = tempfile::tempdir().unwrap();
        let path = model_file(dir.path(), |_, meta| {
            assert!(meta.remove("ivp.depth_head_mult").is_some());
        });
        assert_eq!(load_model(&path).unwrap().1.depth_head_mult, 1.0);
    }

    #[test]
    fn a_scaled_depth_head_round_trips_and_its_metadata_must_match() {
        let dir = tempfile::tempdir().unwrap();
        let config = SMALL.with_depth_head_mult(0.5);
        let path = dir.path().join("model.safetensors");
        let (net, varmap) = IvpNet::seeded(config, 3).unwrap();
        save_model(&path, &varmap, &config, None).unwrap();
        let (loaded, loaded_config) = load_model(&path).unwrap();
        assert_eq!(loaded_config, config);
        assert_eq!(net.config(), loaded.config());
        let (tensors, mut metadata) = read(&path, MODEL_FORMAT).unwrap();
        assert_eq!(tensors["depth.c2.weight"].dims(), [16, 8, 7, 7]);
        metadata.insert("ivp.depth_head_mult".into(), "1".into());
        write(&path, tensors.into_iter().collect(), metadata).unwrap();
        let err = load_err(&path);
        assert!(err.contains("`depth.c1.") && err.contains("has shape"), "{err}");
    }

    #[test]
    fn metadata_is_checked_against_the_weights_before_building() {
        let dir = tempfile::tempdir().unwrap();
        for (m, fragment) in [("1e9", "out of range"), ("0.1", "not whole numbers"), ("0.25", "does not match")] {
            let path = model_file(dir.path(), |_, meta| {
                meta.insert("ivp.width_mult".into(), m.into());
            });
            let err = load_err(&path);
            assert!(err.contains(fragment), "{m}: {err}");
        }
        let path = model_file(dir.path(), |_, meta| {
            meta.insert("ivp.variant".into(), "intensity".into());
        });
        // The variant changes a few layers' channels, not the widths: the strict load names one.
        let err = load_err(&path);
        assert!(err.contains("has shape") && err.contains("expected"), "{err}");
    }

    #[test]
    fn broken_weights_are_refused_naming_the_tensor() {
        let dir = tempfile::tempdir().unwrap();
        for (value, fragment) in [(f32::NAN, "non-finite"), (f32::INFINITY, "non-finite"), (1e30, "1e30")] {
            let path = model_file(dir.path(), |tensors, _| {
                let t = &tensors["e3.bias"];
                let mut v = t.to_vec1::<f32>().unwrap();
                v[1] = value;
                tensors.insert("e3.bias".into(), Tensor::from_vec(v, t.dims(), &Device::Cpu).unwrap());
            });
            let err = load_err(&path);
            assert!(err.contains("tensor `e3.bias`") && err.contains(fragment), "{value}: {err}");
        }
    }
}
