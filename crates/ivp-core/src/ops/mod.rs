//! Neural-network operators for candle that are faster on CPU than candle's own.

pub mod conv2d;
pub mod resize;
pub mod sampler;

pub use conv2d::conv2d;
