//! The lowest layer: images, cameras, forward warping, hole classification, frame views, the
//! nearest-known search and the known-pixels-only read. Imports nothing else of the crate.

pub mod camera;
pub mod frame;
pub mod holes;
pub mod image;
pub mod known_read;
pub mod nearest;
pub mod shrink;
pub mod warp;

pub use camera::{relative_pose, Intrinsics, WorldToCamera};
pub use frame::{Direction, FrameView, Pixel};
pub use holes::{within_reach, HoleMask, PixelClass};
pub use image::{DepthMap, Image, Rect, RgbImage, VectorField};
pub use known_read::{sample_known, KnownRead};
pub use nearest::NearestKnown;
pub use warp::{splat_field, warp_forward, warp_known, Warp};
