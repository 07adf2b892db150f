//! `ivp eval --report DIR`: an evaluation as a folder that any browser opens without a server: the
//! table of scores, charts when there are several models, and per target frame its worst
//! disocclusion regions magnified, as every method filled them, with error maps and vectors.
//!
//! - `collect`: what is kept of each frame while the evaluation runs (crops, a thumbnail).
//! - `regions`: which regions of a frame are shown (connected disocclusions, ranked by error).
//! - `colours`: the error scale, holes marked, legends, thumbnails.
//! - `charts`: D-MSE against time, and D-MSE by method (SVG).
//! - `page`: the HTML.
//! - `write`: the folder checked, then the images and the page written.
//! - `error`: what can go wrong while writing one.

pub mod charts;
pub mod collect;
pub mod colours;
pub mod error;
pub mod page;
pub mod regions;
pub mod write;

pub use collect::{MethodInfo, ReportCollector, ReportOptions};
pub use error::ReportError;
pub use page::{command_line, describe_machine, PageContext};
pub use write::{prepare_report_dir, write_report, WrittenReport, PAGE};
