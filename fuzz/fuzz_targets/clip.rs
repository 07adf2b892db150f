//! Clip folders with one file damaged (poses, intrinsics, a depth EXR, an image, a frame's name).
#![no_main]

use std::sync::OnceLock;

use ivp_tests::fuzz::ClipHarness;
use libfuzzer_sys::fuzz_target;

static HARNESS: OnceLock<ClipHarness> = OnceLock::new();

fuzz_target!(|input: &[u8]| {
    let _ = HARNESS.get_or_init(ClipHarness::new).run(input);
});
