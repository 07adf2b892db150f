//! `ivp export --onnx`: the network of a vector variant as one ONNX graph (MODEL.md, "ONNX").
//!
//! - `graph`: the graph, layer by layer as `IvpNet::masked_output` computes it.
//! - `proto`: the messages of `onnx.proto` the graph is written in, encoded by prost.
//! - `export`: a model file or checkpoints (averaged) to a `.onnx` file, written durably.

mod export;
mod graph;
pub mod proto;

pub use export::{export_onnx, OnnxExportError};
pub use graph::{onnx_model, GraphError, IR_VERSION, OPSET};
