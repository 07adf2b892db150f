//! A model file or checkpoints to an ONNX file.

use std::path::{Path, PathBuf};

use ivp_core::nn::model::ModelConfig;
use prost::Message;

use super::graph::{onnx_model, GraphError};
use crate::checkpoint::{averaged_model, CheckpointError};

#[derive(Debug, thiserror::Error)]
pub enum OnnxExportError {
    #[error(transparent)]
    Model(#[from] CheckpointError),
    #[error("{}: {source}", path.display())]
    Graph { path: PathBuf, source: Box<GraphError> },
    #[error(transparent)]
    Write(#[from] ivp_data::DataError),
}

/// Writes the network of a model file or checkpoint (the mean of several, as `ivp export`
/// averages them) to `out` as an ONNX graph, atomically and durably. The model file's metadata
/// (`ivp.variant`, `ivp.width_mult`, ...) goes to the graph's `metadata_props`.
pub fn export_onnx(checkpoints: &[PathBuf], out: &Path) -> Result<ModelConfig, OnnxExportError> {
    let model = averaged_model(checkpoints, out)?;
    let graph = onnx_model(&model.net, &model.metadata())
        .map_err(|source| OnnxExportError::Graph { path: checkpoints[0].clone(), source: Box::new(source) })?;
    ivp_data::write_durably(out, &graph.encode_to_vec())?;
    Ok(model.config)
}
