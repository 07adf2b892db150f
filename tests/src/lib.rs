//! Shared helpers of the end-to-end tests in `tests/`.

use std::path::PathBuf;

/// `shared/data/blender-dev`: real Blender renders beside the repository (see the README).
pub fn blender_dev() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/blender-dev");
    assert!(
        dir.is_dir(),
        "{} is missing: the end-to-end tests need the shared data folder beside the repository",
        dir.display()
    );
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
