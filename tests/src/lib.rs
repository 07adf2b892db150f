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
