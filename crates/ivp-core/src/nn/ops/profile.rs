//! Time spent in each operator, for the per-operator breakdown of `ivp bench --profile`.
//!
//! Off by default: a disabled scope costs one relaxed atomic load. candle's own operators
//! (elementwise, concatenation, reductions) are not instrumented; the caller reports them as the
//! difference between the step's wall time and the sum of these totals.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

static ENABLED: AtomicBool = AtomicBool::new(false);
static TOTALS: Mutex<BTreeMap<&'static str, OperatorTime>> = Mutex::new(BTreeMap::new());

/// Total time and number of calls of one operator.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OperatorTime {
    pub total: Duration,
    pub calls: u64,
}

/// Starts (or stops) recording operator times.
pub fn set_enabled(on: bool) {
    ENABLED.store(on, Ordering::Relaxed);
}

/// The totals recorded since the last call, by operator name; clears them.
pub fn take() -> BTreeMap<&'static str, OperatorTime> {
    std::mem::take(&mut *TOTALS.lock().unwrap_or_else(|e| e.into_inner()))
}

/// Runs `f`, adding its wall time to operator `name` when recording is on.
pub(crate) fn timed<T>(name: &'static str, f: impl FnOnce() -> T) -> T {
    if !ENABLED.load(Ordering::Relaxed) {
        return f();
    }
    let start = Instant::now();
    let out = f();
    let elapsed = start.elapsed();
    let mut totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
    let entry = totals.entry(name).or_default();
    entry.total += elapsed;
    entry.calls += 1;
    out
}
