//! Everything of infilling vector prediction that needs no file and no neural network:
//! images, cameras, forward warping, hole classification, temporal priors, classical infillers
//! and the metrics of SPEC §7.

pub mod camera;
pub mod holes;
pub mod image;
pub mod inference;
pub mod infill;
pub mod inpaint;
pub mod iterative;
pub mod loss;
pub mod metrics;
pub mod model;
pub mod ops;
pub mod optim;
pub mod prior;
pub mod warp;

pub use camera::{relative_pose, Intrinsics, WorldToCamera};
pub use holes::{HoleMask, PixelClass};
pub use image::{DepthMap, Image, RgbImage, VectorField};
pub use warp::{splat_field, warp_forward, Warp};
