//! The one error type of this crate. Every message names the file (full path) and the problem, so a
//! user who sees only the message knows what to fix.
//!
//! Underlying causes are part of the message (fields named `cause`) rather than exposed as
//! `Error::source`: an `anyhow` chain printed with `{:#}` would otherwise repeat them.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub type Result<T, E = DataError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The file system refused an operation (`action` says which, e.g. "cannot read").
    #[error("{}: {action}: {cause}", path.display())]
    Io { path: PathBuf, action: &'static str, cause: std::io::Error },

    /// A PNG/JPEG file could not be decoded or encoded (unreadable, truncated, unsupported).
    #[error("{}: {action}: {cause}", path.display())]
    Image { path: PathBuf, action: &'static str, cause: image::ImageError },

    /// An EXR file could not be read or written (unreadable, truncated, unsupported).
    #[error("{}: {action}: {cause}", path.display())]
    Exr { path: PathBuf, action: &'static str, cause: exr::error::Error },

    /// A depth EXR without a channel that the rule of ALGORITHMS.md §3 accepts.
    #[error(
        "{}: no depth channel: expected a single channel or one of {}, found channels [{}]",
        path.display(),
        accepted.join(", "),
        channels.join(", ")
    )]
    NoDepthChannel { path: PathBuf, channels: Vec<String>, accepted: &'static [&'static str] },

    /// A malformed line of a CSV file (1-based line number).
    #[error("{}: line {line}: {problem}", path.display())]
    Csv { path: PathBuf, line: usize, problem: String },

    /// An image or depth map whose size differs from the clip's (or from its partner's).
    #[error(
        "{}: size {}x{} differs from the expected {}x{}",
        path.display(),
        found.0,
        found.1,
        expected.0,
        expected.1
    )]
    SizeMismatch { path: PathBuf, found: (usize, usize), expected: (usize, usize) },

    /// Frame files that are missing, extra or numbered inconsistently; `path` is the clip folder.
    #[error("{}: {problem}", path.display())]
    Frames { path: PathBuf, problem: String },

    /// Any other invalid content or argument.
    #[error("{}: {problem}", path.display())]
    Invalid { path: PathBuf, problem: String },

    /// Training samples that cannot be made (a crop larger than the frames, clips without
    /// disocclusions, ...); `origin` names the clip: its folder, or a generated clip's description.
    #[error("{}: {problem}", origin.display())]
    Sampling { origin: PathBuf, problem: String },

    /// A folder that holds no clip at any depth.
    #[error("{}: no clip found (a clip is a folder holding TransformationMatrices.csv)", path.display())]
    NoClip { path: PathBuf },
}

impl DataError {
    pub fn io(path: &Path, action: &'static str, cause: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), action, cause }
    }

    pub(crate) fn image(path: &Path, action: &'static str, cause: image::ImageError) -> Self {
        Self::Image { path: path.to_path_buf(), action, cause }
    }

    pub(crate) fn exr(path: &Path, action: &'static str, cause: exr::error::Error) -> Self {
        Self::Exr { path: path.to_path_buf(), action, cause }
    }

    pub(crate) fn invalid(path: &Path, problem: impl Into<String>) -> Self {
        Self::Invalid { path: path.to_path_buf(), problem: problem.into() }
    }

    pub(crate) fn csv(path: &Path, line: usize, problem: impl Into<String>) -> Self {
        Self::Csv { path: path.to_path_buf(), line, problem: problem.into() }
    }

    pub(crate) fn frames(path: &Path, problem: impl Into<String>) -> Self {
        Self::Frames { path: path.to_path_buf(), problem: problem.into() }
    }

    /// The path the error is about.
    pub fn path(&self) -> &Path {
        match self {
            Self::Io { path, .. }
            | Self::Image { path, .. }
            | Self::Exr { path, .. }
            | Self::NoDepthChannel { path, .. }
            | Self::Csv { path, .. }
            | Self::SizeMismatch { path, .. }
            | Self::Frames { path, .. }
            | Self::Invalid { path, .. }
            | Self::Sampling { origin: path, .. }
            | Self::NoClip { path } => path,
        }
    }
}

/// Joins paths for a message, shortening long lists (a clip may miss hundreds of frames).
pub(crate) fn list_paths(paths: &[PathBuf]) -> String {
    const SHOWN: usize = 8;
    let mut s = String::new();
    for (i, p) in paths.iter().take(SHOWN).enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        let _ = write!(s, "{}", p.display());
    }
    if paths.len() > SHOWN {
        let _ = write!(s, " and {} more", paths.len() - SHOWN);
    }
    s
}
