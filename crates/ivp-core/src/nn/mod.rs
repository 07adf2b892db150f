//! The neural network and what trains it: candle custom operators with hand-written backward
//! passes (`ops`), the network of ALGORITHMS.md §6.1 (`model`), the losses of ALGORITHMS.md §6.4 (`loss`), Adam
//! with saveable state (`optim`) and the image <-> tensor conversion (`tensor`).
//!
//! Layer: imports `geometry` (images) and `metrics` (the SSIM parameters), never `infill` or
//! `prior`: the network sees tensors, and reaches infilling only through `inference`.

pub mod loss;
pub mod model;
pub mod ops;
pub mod optim;
pub mod tensor;

pub use model::{IvpNet, ModelConfig, NetInput, Variant};
pub use tensor::{from_tensor, to_batch_tensor, to_tensor};
