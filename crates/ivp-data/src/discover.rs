//! Finding clips in a dataset folder (ALGORITHMS.md §3: a clip is a folder with `TransformationMatrices.csv`).

use std::collections::HashSet;
use std::fs;
use std::path::{Path, PathBuf};

use crate::csv::POSES_FILE;
use crate::error::{DataError, Result};

/// Every clip folder under `root` at any depth (`root` itself included), sorted. Errors if `root`
/// cannot be read or holds no clip. Symbolic links are followed, each real folder visited once.
pub fn find_clips(root: impl AsRef<Path>) -> Result<Vec<PathBuf>> {
    let root = root.as_ref();
    let meta = fs::metadata(root).map_err(|e| DataError::io(root, "cannot open dataset folder", e))?;
    if !meta.is_dir() {
        return Err(DataError::invalid(root, "not a folder"));
    }
    let mut clips = Vec::new();
    let mut visited = HashSet::new();
    collect_clips(root, &mut visited, &mut clips)?;
    if clips.is_empty() {
        return Err(DataError::NoClip { path: root.to_path_buf() });
    }
    clips.sort();
    Ok(clips)
}

fn collect_clips(dir: &Path, visited: &mut HashSet<PathBuf>, clips: &mut Vec<PathBuf>) -> Result<()> {
    // Canonical paths break cycles made by symbolic links.
    let real = fs::canonicalize(dir).map_err(|e| DataError::io(dir, "cannot resolve folder", e))?;
    if !visited.insert(real) {
        return Ok(());
    }
    if dir.join(POSES_FILE).is_file() {
        clips.push(dir.to_path_buf());
    }
    let entries = fs::read_dir(dir).map_err(|e| DataError::io(dir, "cannot list folder", e))?;
    for entry in entries {
        let path = entry.map_err(|e| DataError::io(dir, "cannot list folder", e))?.path();
        if path.is_dir() {
            collect_clips(&path, visited, clips)?;
        }
    }
    Ok(())
}
