//! Infilling vector prediction without files: images, cameras, forward warping, hole
//! classification, temporal priors, classical infillers, the network with its operators and
//! losses, and the metrics of ALGORITHMS.md §7.
//!
//! The modules are layers; each imports only from the layers below it (a test in
//! `tests/tests/layering.rs` keeps it so):
//!
//! ```text
//! inference                  the network as a vector predictor and as an infiller
//! infill        nn           infilling methods | operators, model, losses, Adam, tensors
//! prior         metrics      temporal prior    | MSE, SSIM, D-MSE, D-SSIM, TC
//! geometry                   images, cameras, warps, holes, nearest-known search, known reads
//! ```
//!
//! `infill` and `nn` never import each other; `nn` imports `metrics` for the SSIM parameters.

pub mod geometry;
pub mod inference;
pub mod infill;
pub mod metrics;
pub mod nn;
pub mod prior;

#[cfg(test)]
mod test_scene;

pub use geometry::{relative_pose, splat_field, warp_forward, Warp};
pub use geometry::{DepthMap, Image, RgbImage, VectorField};
pub use geometry::{HoleMask, Intrinsics, PixelClass, WorldToCamera};
