//! Evaluation, training, benchmarks and export behind the `ivp` command-line program.
//!
//! - `cli`: the `ivp` command line (clap arguments and a thin `run_*` per subcommand).
//! - `eval`: the evaluation harness: methods built from their names, scored on every target of
//!   every clip (ALGORITHMS.md §7), the table and the JSON report.
//! - `report`: `ivp eval --report DIR`: an evaluation as an HTML page with crops of every frame's
//!   worst disocclusion regions, error maps, vectors and charts (a folder any browser opens).
//! - `export_warps`: warped frames on disk (`ivp warp`), and every evaluation target exported for
//!   other tools.
//! - `check`: which reading of a clip's poses, axes and depth units explains its images.
//! - `train`: the training configuration, the loop (validation, checkpoints, resume) and one step.
//! - `guide`: the guide term of the first training steps, its target and its choice in a configuration.
//! - `distributed`: data-parallel training: the ranks of a job (one process, or MPI with the `mpi`
//!   feature), the batch split, the fixed-order gradient all-reduce, rank 0's state for every rank.
//! - `metrics_csv`: the rows of a run's `metrics.csv`, written and read back on resume.
//! - `validation`: the fixed validation frames of a run (generated, 320x240 and 1080p), scored the
//!   way `eval` scores.
//! - `checkpoint`: model files and checkpoints, saved and strictly loaded.
//! - `onnx`: the network of a model file as an ONNX graph (`ivp export --onnx`).
//! - `demo`: `ivp demo`'s decisions: reuse or train, which clips to score on, which methods.
//! - `infer`: a trained model on one target (`ivp infer`) or on every other frame (`ivp upsample`).
//! - `bench`: one training step or one inference timed on random inputs (`ivp bench train|infer`).
//! - `bench_frame`: one frame end to end, generated or each target of a clip, by stage (`ivp bench frame`).
//! - `machine`: the CPU a time was measured on, reported beside every time.
//! - `plot`: `loss.png` of a run.
//! - `sheet`: labelled contact sheets, flow colours, and the sheet of a training sample.
//! - `progress`: the progress bar every long-running command shows.

pub mod bench;
pub mod bench_frame;
pub mod check;
pub mod checkpoint;
pub mod cli;
pub mod demo;
pub mod distributed;
pub mod eval;
pub mod export_warps;
pub mod guide;
pub mod infer;
pub mod machine;
pub mod metrics_csv;
pub mod onnx;
pub mod plot;
pub mod progress;
pub mod report;
pub mod sheet;
pub mod train;
pub mod validation;
