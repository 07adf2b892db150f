//! Replays the committed fuzzing corpus (`fuzz/corpus/`, found by `cargo fuzz`, see fuzz/README.md)
//! through the same harness as the fuzz targets: every input must open, load and check cleanly or
//! fail with an error that names its file, without a panic.

use std::path::PathBuf;

use ivp_tests::fuzz::{ClipHarness, ModelHarness};

fn corpus(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus").join(target);
    let mut inputs: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            (path, bytes)
        })
        .collect();
    inputs.sort();
    assert!(inputs.len() >= 5, "{}: the corpus has only {} inputs", dir.display(), inputs.len());
    inputs
}

/// Runs every input of `target`'s corpus: none may panic, and the corpus must hold both inputs
/// that are accepted (intact files) and inputs that are refused (damaged ones).
fn replay(target: &str, run: impl Fn(&[u8]) -> Result<(), String>) {
    let (mut accepted, mut refused) = (0, 0);
    for (path, input) in corpus(target) {
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(&input))) {
            Ok(Ok(())) => accepted += 1,
            Ok(Err(_)) => refused += 1,
            Err(_) => panic!("{}: the {target} harness panicked", path.display()),
        }
    }
    assert!(accepted > 0 && refused > 0, "{target}: accepted {accepted}, refused {refused}");
}

#[test]
fn clip_corpus_gives_clear_verdicts() {
    let harness = ClipHarness::new();
    replay("clip", |input| harness.run(input));
}

#[test]
fn model_corpus_gives_clear_verdicts() {
    let harness = ModelHarness::new();
    replay("model", |input| harness.run(input));
}

#[test]
fn the_base_clip_is_accepted_and_every_seed_too() {
    let harness = ClipHarness::new();
    let seeds = harness.seeds();
    for seed in &seeds[..4] {
        harness.run(seed).unwrap_or_else(|e| panic!("seed {}: {e}", seed[0]));
    }
    // A stray image without its depth file is refused, naming the missing file.
    let error = harness.run(&seeds[4]).unwrap_err();
    assert!(error.contains("depth/0003.exr"), "{error}");
    // A damaged pose file is refused with the file's name.
    let error = harness.run(b"\0not,a,pose").unwrap_err();
    assert!(error.contains("TransformationMatrices.csv"), "{error}");
}

/// `cargo test -p ivp-tests --test fuzz_corpus -- --ignored` rewrites the seeds (fuzz/README.md).
#[test]
#[ignore = "writes the corpus seeds into the repository"]
fn write_corpus_seeds() {
    ivp_tests::fuzz::write_seeds(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus")).unwrap();
}
