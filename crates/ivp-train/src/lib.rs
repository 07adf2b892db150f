//! Evaluation (and later training and export) behind the `ivp` command-line program.

pub mod check;
pub mod eval;
pub mod sheet;
