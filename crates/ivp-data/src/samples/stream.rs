//! Batches made ahead of time on background threads and delivered strictly in step order.
//!
//! Workers take steps in order, at most `prefetch` ahead of the consumer, and compute each batch
//! with [`SampleGenerator::batch`], a pure function of the step: the batches do not depend on the
//! number of workers, on which worker made which, or on the order they finish in. A worker with
//! nothing to compute loads the clips that the coming steps will need, so that rendering a new
//! clip rarely holds up a batch. Clips no pending step needs are freed as batches are delivered.

use std::collections::{BTreeMap, HashSet};
use std::ops::Range;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;

use super::batch::Batch;
use super::generator::SampleGenerator;
use crate::error::{DataError, Result};

/// How a stream runs; unlike [`SampleConfig`](super::SampleConfig), nothing here changes the batches.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StreamOptions {
    /// Background threads, each on one core (its warps run single-threaded), so that training keeps
    /// the others. 0 computes every batch on the consumer's thread when it asks for it.
    pub workers: usize,
    /// Batches computed ahead of the consumer, at most.
    pub prefetch: usize,
}

impl Default for StreamOptions {
    fn default() -> Self {
        Self { workers: 1, prefetch: 4 }
    }
}

/// Clips past the pools of the pending steps that idle workers load in advance.
const LOOKAHEAD_CLIPS: u64 = 1;

/// An endless sequence of batches starting at any step (to resume a run); see the module docs.
/// Dropping it stops the workers (each finishes the batch it is on) and joins them.
pub struct SampleStream {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
}

struct Shared {
    generator: Arc<SampleGenerator>,
    prefetch: u64,
    state: Mutex<State>,
    /// Signalled when workers may find something to do: a batch was delivered, or shutdown.
    work_available: Condvar,
    /// Signalled when a worker has finished a batch.
    batch_finished: Condvar,
}

struct State {
    /// The step the consumer receives next.
    next_delivery: u64,
    /// The first step no worker has taken yet.
    next_unclaimed: u64,
    finished: BTreeMap<u64, Result<Batch>>,
    /// Arrivals whose preload failed: the batch that needs them loads them itself and reports the error.
    failed_preloads: HashSet<u64>,
    shutting_down: bool,
}

enum Job {
    Batch(u64),
    Preload(u64),
    Exit,
}

impl SampleStream {
    /// Starts delivering batches at `first_step`.
    pub fn start(generator: Arc<SampleGenerator>, first_step: u64, options: StreamOptions) -> Result<Self> {
        let state = State {
            next_delivery: first_step,
            next_unclaimed: first_step,
            finished: BTreeMap::new(),
            failed_preloads: HashSet::new(),
            shutting_down: false,
        };
        let shared = Arc::new(Shared {
            generator,
            prefetch: options.prefetch.max(1) as u64,
            state: Mutex::new(state),
            work_available: Condvar::new(),
            batch_finished: Condvar::new(),
        });
        // Built before the threads, so that a failed spawn drops it and joins those already started.
        let mut stream = Self { shared, workers: Vec::with_capacity(options.workers) };
        for index in 0..options.workers {
            let shared = stream.shared.clone();
            let thread = std::thread::Builder::new()
                .name(format!("ivp-samples-{index}"))
                .spawn(move || run_worker(&shared))
                .map_err(|e| stream_error(format!("cannot start sample worker thread: {e}")))?;
            stream.workers.push(thread);
        }
        Ok(stream)
    }

    /// The step of the batch that [`next_batch`](Self::next_batch) returns next.
    pub fn next_step(&self) -> u64 {
        self.shared.lock().next_delivery
    }

    pub fn generator(&self) -> &Arc<SampleGenerator> {
        &self.shared.generator
    }

    /// The batch of the next step, waiting for it if needed. An error concerns that step only:
    /// the stream moves on to the next one.
    pub fn next_batch(&mut self) -> Result<Batch> {
        let shared = &self.shared;
        let mut state = shared.lock();
        let step = state.next_delivery;
        let result = if self.workers.is_empty() {
            shared.generator.batch(step)
        } else {
            loop {
                if let Some(result) = state.finished.remove(&step) {
                    break result;
                }
                state = shared.batch_finished.wait(state).unwrap_or_else(PoisonError::into_inner);
            }
        };
        state.next_delivery = step + 1;
        state.next_unclaimed = state.next_unclaimed.max(step + 1);
        let wanted = shared.wanted_arrivals(&state);
        drop(state);
        shared.generator.keep_only(wanted);
        shared.work_available.notify_all();
        result
    }
}

impl Iterator for SampleStream {
    type Item = Result<Batch>;

    /// Never `None`: the stream is endless.
    fn next(&mut self) -> Option<Result<Batch>> {
        Some(self.next_batch())
    }
}

impl Drop for SampleStream {
    fn drop(&mut self) {
        self.shared.lock().shutting_down = true;
        self.shared.work_available.notify_all();
        for worker in self.workers.drain(..) {
            // Panics inside a batch are caught and reported as errors: a join error is a bug.
            if worker.join().is_err() {
                tracing::error!("a sample worker thread panicked outside a batch");
            }
        }
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // Batches are computed outside the lock: a poisoned state is still consistent.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The arrivals that the steps workers may take next draw from, and a few beyond.
    fn wanted_arrivals(&self, state: &State) -> Range<u64> {
        let pending = state.next_delivery..state.next_delivery + self.prefetch;
        self.generator.arrivals_for(pending, LOOKAHEAD_CLIPS)
    }

    /// Waits for the next thing to do: the next step if it is within `prefetch` of the consumer,
    /// else a clip to load ahead of time.
    fn next_job(&self) -> Job {
        let mut state = self.lock();
        loop {
            if state.shutting_down {
                return Job::Exit;
            }
            if state.next_unclaimed < state.next_delivery + self.prefetch {
                state.next_unclaimed += 1;
                return Job::Batch(state.next_unclaimed - 1);
            }
            let mut wanted = self.wanted_arrivals(&state);
            if let Some(arrival) = wanted.find(|&a| !state.failed_preloads.contains(&a) && !self.generator.is_loaded(a))
            {
                return Job::Preload(arrival);
            }
            state = self.work_available.wait(state).unwrap_or_else(PoisonError::into_inner);
        }
    }
}

/// A worker: its own single-thread rayon pool, so that the warps of its batches use one core.
fn run_worker(shared: &Shared) {
    let work = || loop {
        match shared.next_job() {
            Job::Exit => return,
            Job::Batch(step) => {
                let result = catch_unwind(AssertUnwindSafe(|| shared.generator.batch(step))).unwrap_or_else(|panic| {
                    Err(stream_error(format!("computing batch {step} panicked: {}", panic_message(&panic))))
                });
                shared.lock().finished.insert(step, result);
                shared.batch_finished.notify_all();
            }
            Job::Preload(arrival) => {
                let outcome = catch_unwind(AssertUnwindSafe(|| shared.generator.preload(arrival)));
                if !matches!(outcome, Ok(None | Some(Ok(())))) {
                    shared.lock().failed_preloads.insert(arrival);
                }
            }
        }
    };
    // A scoped pool joins its thread before returning: nothing outlives the stream.
    let pooled =
        rayon::ThreadPoolBuilder::new().num_threads(1).build_scoped(|thread| thread.run(), |pool| pool.install(work));
    if let Err(e) = pooled {
        // Without a pool of its own the worker still works, on the global one.
        tracing::warn!("sample worker: no single-thread pool ({e}), using the global one");
        work();
    }
}

fn stream_error(problem: String) -> DataError {
    DataError::Sampling { origin: PathBuf::from("sample stream"), problem }
}

fn panic_message(panic: &Box<dyn std::any::Any + Send>) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}
