//! What can go wrong while writing a report.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{0} exists and is not empty: choose another folder for the report, or pass --force to write into it")]
    NotEmpty(PathBuf),
    #[error("{0} exists and is not a folder")]
    NotAFolder(PathBuf),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Data(#[from] ivp_data::DataError),
    #[error("drawing {what}: {message}")]
    Drawing { what: &'static str, message: String },
}
