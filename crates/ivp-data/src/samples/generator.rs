//! The deterministic sampler: the samples of step `s` are a pure function of `(config, split, s)`
//! and the source's clips, whichever thread computes them and whatever was computed before.
//!
//! Clips enter a rolling pool in a fixed sequence of *arrivals*: at step `s` the pool holds
//! arrivals `s / refresh_every .. s / refresh_every + pool_size`, so every `refresh_every` steps
//! one clip leaves and the next enters, and each clip serves `pool_size * refresh_every` steps.
//! Sample `j` of step `s` draws its clip (from the pool), direction, target and crop centre from a
//! generator seeded by `hash(seed, split, s, j)`.

use std::collections::HashSet;
use std::ops::Range;
use std::path::PathBuf;
use std::sync::Arc;

use super::batch::Batch;
use super::cache::{ClipCache, LoadedClip};
use super::rng::{hash_words, Rng};
use super::sample::Sample;
use super::source::ClipSource;
use super::target::Playback;
use crate::error::{DataError, Result};

/// Everything but the step that a batch depends on (with the source's clips and the split).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct SampleConfig {
    pub seed: u64,
    /// Side of the square crops (ALGORITHMS.md §5: 256).
    pub crop: usize,
    /// Samples per batch (the reference trains with 8).
    pub batch_size: usize,
    /// Clips that the samples of one step are drawn from.
    pub pool_size: usize,
    /// Steps between two arrivals in the pool.
    pub refresh_every: u64,
}

impl Default for SampleConfig {
    fn default() -> Self {
        Self { seed: 0, crop: 256, batch_size: 8, pool_size: 4, refresh_every: 16 }
    }
}

/// Training and validation draw from disjoint streams of clips and crops: every seed is hashed
/// with the split, so the same `SampleConfig::seed` gives unrelated clips in the two.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Split {
    Train,
    Validation,
}

impl Split {
    /// Domain-separation tag: the name in ASCII.
    fn tag(self) -> u64 {
        u64::from_le_bytes(*match self {
            Split::Train => b"train\0\0\0",
            Split::Validation => b"valid\0\0\0",
        })
    }
}

/// What a random draw is for: hashed with the seed so that the streams never overlap.
#[derive(Clone, Copy)]
#[repr(u64)]
enum Purpose {
    /// The seed handed to the source for a clip.
    ClipSeed = 1,
    /// The order of a finite collection's clips within one pass over it.
    ClipOrder = 2,
    /// The choices of one sample.
    Sample = 3,
}

/// Draws of (clip, direction, target) before giving up on finding a disocclusion. A pool holds
/// at most `pool_size * 2 * (frames - 3)` targets, so this many draws visit all of them in practice.
const MAX_DRAWS: usize = 1000;

/// Cuts samples and batches of any step on demand; clips are loaded once and shared.
pub struct SampleGenerator {
    source: Arc<dyn ClipSource>,
    config: SampleConfig,
    split: Split,
    cache: ClipCache,
    /// The samples of each batch this generator makes: all of them, or one process's part of a
    /// batch split across processes ([`SampleGenerator::with_batch_part`]).
    batch_part: Range<usize>,
}

impl SampleGenerator {
    /// Errors on a zero crop, batch, pool or refresh period, or an empty finite source.
    pub fn new(source: Arc<dyn ClipSource>, config: SampleConfig, split: Split) -> Result<Self> {
        let invalid = |problem: &str| {
            Err(DataError::Sampling { origin: PathBuf::from("sample configuration"), problem: problem.into() })
        };
        if config.crop == 0 || config.batch_size == 0 || config.pool_size == 0 || config.refresh_every == 0 {
            return invalid(&format!("crop, batch size, pool size and refresh period must be positive: {config:?}"));
        }
        if source.clip_count() == Some(0) {
            return invalid("the clip source holds no clip");
        }
        let batch_part = 0..config.batch_size;
        Ok(Self { source, config, split, cache: ClipCache::default(), batch_part })
    }

    /// Makes batches of samples `part` of each step only (a range within `0..batch_size`): one
    /// process's part of a batch split across processes. Each sample is the one the whole batch
    /// holds at that index, so the parts of all processes make up the whole batch.
    pub fn with_batch_part(mut self, part: Range<usize>) -> Result<Self> {
        if part.is_empty() || part.end > self.config.batch_size {
            return Err(DataError::Sampling {
                origin: PathBuf::from("sample configuration"),
                problem: format!("samples {part:?} are not a part of a batch of {}", self.config.batch_size),
            });
        }
        self.batch_part = part;
        Ok(self)
    }

    pub fn config(&self) -> &SampleConfig {
        &self.config
    }

    pub fn split(&self) -> Split {
        self.split
    }

    pub fn source(&self) -> &Arc<dyn ClipSource> {
        &self.source
    }

    /// The arrivals in the pool at `step`.
    pub fn pool(&self, step: u64) -> Range<u64> {
        let first = step / self.config.refresh_every;
        first..first + self.config.pool_size as u64
    }

    /// The source's clip behind arrival `arrival`: the arrival itself for an endless source; for
    /// `n` clips, passes over the collection, each in its own shuffled order.
    pub fn clip_id(&self, arrival: u64) -> u64 {
        match self.source.clip_count() {
            None => arrival,
            Some(n) => self.pass_order(arrival / n, n)[(arrival % n) as usize],
        }
    }

    /// The seed handed to the source for clip `id`.
    pub fn clip_seed(&self, id: u64) -> u64 {
        hash_words(&[self.config.seed, self.split.tag(), Purpose::ClipSeed as u64, id])
    }

    /// Sample `j` of step `step` (any `j`, though a batch holds `0..batch_size`).
    pub fn sample(&self, step: u64, j: usize) -> Result<Sample> {
        let seed_words = [self.config.seed, self.split.tag(), Purpose::Sample as u64, step, j as u64];
        let mut rng = Rng::from_words(&seed_words);
        let pool = self.pool(step);
        for _ in 0..MAX_DRAWS {
            let clip = self.clip(pool.start + rng.below(self.config.pool_size as u64))?;
            let direction = Playback::BOTH[rng.index(2)];
            let targets = clip.targets_per_direction();
            if targets == 0 {
                continue;
            }
            let Some(target) = clip.target(direction, rng.index(targets)) else {
                continue;
            };
            let centre = rng.index(target.disocclusions.len());
            let origin = (clip.id, clip.name.clone(), direction);
            return Ok(Sample::cut(&clip.frames, target, centre, self.config.crop, origin));
        }
        let first = self.clip_id(pool.start);
        Err(DataError::Sampling {
            origin: self.source.origin(first, self.clip_seed(first)),
            problem: format!(
                "no disocclusion found in {MAX_DRAWS} draws of a target from the clips of the pool at step {step} \
                 (arrivals {pool:?}): clips need at least 4 frames and a moving camera"
            ),
        })
    }

    /// The samples of batch `step` (those of its part, see [`SampleGenerator::with_batch_part`]).
    pub fn samples(&self, step: u64) -> Result<Vec<Sample>> {
        self.batch_part.clone().map(|j| self.sample(step, j)).collect()
    }

    /// Batch `step` (its part) as tensors.
    pub fn batch(&self, step: u64) -> Result<Batch> {
        Ok(Batch::from_samples(step, &self.samples(step)?))
    }

    /// The arrivals that steps `steps` draw from, and `lookahead` more after them.
    pub fn arrivals_for(&self, steps: Range<u64>, lookahead: u64) -> Range<u64> {
        if steps.is_empty() {
            return 0..0;
        }
        self.pool(steps.start).start..self.pool(steps.end - 1).end + lookahead
    }

    /// Frees every cached clip that is not behind one of `arrivals`.
    pub fn keep_only(&self, arrivals: Range<u64>) {
        match self.source.clip_count() {
            None => self.cache.retain(|id| arrivals.contains(&id)),
            Some(_) => {
                let ids: HashSet<u64> = arrivals.map(|a| self.clip_id(a)).collect();
                self.cache.retain(|id| ids.contains(&id));
            }
        }
    }

    /// Whether the clip behind `arrival` is loaded (or being loaded).
    pub fn is_loaded(&self, arrival: u64) -> bool {
        self.cache.contains(self.clip_id(arrival))
    }

    /// Loads the clip behind `arrival` ahead of time, unless some thread has already started;
    /// never waits. `None` if there was nothing to do.
    pub fn preload(&self, arrival: u64) -> Option<Result<()>> {
        let id = self.clip_id(arrival);
        self.cache.load_if_absent(id, || self.load(id))
    }

    fn clip(&self, arrival: u64) -> Result<Arc<LoadedClip>> {
        let id = self.clip_id(arrival);
        self.cache.get_or_load(id, || self.load(id))
    }

    fn load(&self, id: u64) -> Result<LoadedClip> {
        let seed = self.clip_seed(id);
        let name = self.source.origin(id, seed);
        let frames = self.source.load(id, seed)?;
        frames.check(&name, self.config.crop)?;
        tracing::debug!(clip = %name.display(), frames = frames.len(), "loaded training clip");
        Ok(LoadedClip::new(id, name, frames))
    }

    /// The order of the clips of a `n`-clip source in pass `pass` (Fisher-Yates).
    fn pass_order(&self, pass: u64, n: u64) -> Vec<u64> {
        let mut rng = Rng::from_words(&[self.config.seed, self.split.tag(), Purpose::ClipOrder as u64, pass]);
        let mut order: Vec<u64> = (0..n).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, rng.index(i + 1));
        }
        order
    }

    #[cfg(test)]
    pub(crate) fn cached_clip_ids(&self) -> Vec<u64> {
        self.cache.loaded_ids()
    }
}

/// A fixed validation set: batches `0..batches` of the [`Split::Validation`] stream of `source`.
/// It depends only on `(source, config)`; keep `config.seed` fixed across runs to compare them.
pub fn validation_batches(source: Arc<dyn ClipSource>, config: SampleConfig, batches: u64) -> Result<Vec<Batch>> {
    let generator = SampleGenerator::new(source, config, Split::Validation)?;
    (0..batches)
        .map(|step| {
            let batch = generator.batch(step);
            // Validation steps are visited once, in order: free the clips left behind.
            generator.keep_only(generator.arrivals_for(step + 1..batches, 0));
            batch
        })
        .collect()
}
