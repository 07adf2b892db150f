//! Shared helpers of the end-to-end tests in `tests/`.

use std::path::PathBuf;

pub mod fuzz;

/// `data/blender-dev`: real Blender renders kept in the repository (data/README.md).
pub fn blender_dev() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/blender-dev");
    assert!(dir.is_dir(), "{} is missing: it is part of the repository (data/README.md)", dir.display());
    dir
}

/// `shared/bench/torch_reference.py`: the PyTorch reference network, sampler and losses.
pub fn torch_reference_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/bench")
}

/// True when `python3` can import every module named; tests that need them say plainly that they
/// skipped otherwise.
pub fn python_has(modules: &[&str]) -> bool {
    std::process::Command::new("python3")
        .arg("-c")
        .arg(format!("import {}", modules.join(", ")))
        .output()
        .is_ok_and(|o| o.status.success())
}
