//! Evaluation, training, benchmarks and export behind the `ivp` command-line program.

pub mod bench;
pub mod check;
pub mod checkpoint;
pub mod eval;
pub mod infer;
pub mod plot;
pub mod sheet;
pub mod train;
pub mod validation;
