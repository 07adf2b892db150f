//! Model files and checkpoints.
#![no_main]

use std::sync::OnceLock;

use ivp_tests::fuzz::ModelHarness;
use libfuzzer_sys::fuzz_target;

static HARNESS: OnceLock<ModelHarness> = OnceLock::new();

fuzz_target!(|input: &[u8]| {
    let _ = HARNESS.get_or_init(ModelHarness::new).run(input);
});
