//! Training samples (ALGORITHMS.md §5, §6.2): crops of warped frames, priors and ground truth, made from
//! clips of a dataset folder or of generated scenes, deterministically and in the background.
//!
//! ```text
//! ClipSource (DatasetSource, SyntheticSource, FnSource)
//!   --SampleGenerator: rolling pool of clips, per-(clip, direction, target) warps + prior, crops--> Sample
//!   --Batch::from_samples--> Batch (candle tensors, NCHW)
//! SampleStream: SampleGenerator::batch(s) on worker threads, delivered in step order
//! ```
//!
//! For target `t = n + 1` of a clip (frames `n - 2`, `n`, `t`): warp `n - 2 -> n` (`f^w_n` and its
//! holes), fictitious vectors on those holes measured on `f_n`, warp `n -> t` (`f^w_t`, `d^w_t`,
//! holes of `t`), and the temporal prior of `t`. These are computed once per (clip, direction,
//! target) and shared by every crop of it. A crop is centred on a uniformly drawn disocclusion
//! pixel of the warp `n -> t` and shifted inside the frame. Every clip serves both directions
//! (the reversed frame sequence is another trajectory), all targets with `n - 2 >= 0`, and many
//! crops.
//!
//! Determinism: batch `s` is a pure function of `(SampleConfig, Split, s)` and the source's clips;
//! see [`SampleGenerator`] and [`SampleStream`].

mod batch;
mod cache;
mod crop;
mod generator;
mod rng;
mod sample;
mod source;
mod stream;
mod synthetic;
mod target;

#[cfg(test)]
mod tests;

pub use batch::Batch;
pub use crop::CropWindow;
pub use generator::{validation_batches, SampleConfig, SampleGenerator, Split};
pub use sample::{Sample, SampleOrigin};
pub use source::{ClipFrames, ClipSource, DatasetSource, FnSource};
pub use stream::{SampleStream, StreamOptions};
pub use synthetic::SyntheticSource;
pub use target::{Playback, TargetFrames};
