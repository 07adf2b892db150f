//! Clips in memory, shared by every thread that cuts samples from them. A clip is loaded (or
//! rendered) once, by whichever thread first needs it; its targets are prepared lazily, also once.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, OnceLock, PoisonError};

use super::source::ClipFrames;
use super::target::{Playback, PreparedTarget, TargetFrames};
use crate::error::Result;

/// A clip's frames and its prepared targets.
#[derive(Debug)]
pub(crate) struct LoadedClip {
    pub id: u64,
    pub name: PathBuf,
    pub frames: ClipFrames,
    /// Forward targets, then reversed ones; `None` once computed means "no disocclusion".
    targets: Vec<OnceLock<Option<PreparedTarget>>>,
}

impl LoadedClip {
    pub fn new(id: u64, name: PathBuf, frames: ClipFrames) -> Self {
        let count = 2 * TargetFrames::per_direction(frames.len());
        Self { id, name, frames, targets: (0..count).map(|_| OnceLock::new()).collect() }
    }

    pub fn targets_per_direction(&self) -> usize {
        self.targets.len() / 2
    }

    /// Target `i` in `direction`, prepared on first use (a concurrent caller waits for it rather
    /// than computing it twice); `None` if it has no disocclusion.
    pub fn target(&self, direction: Playback, i: usize) -> Option<&PreparedTarget> {
        let per_direction = self.targets_per_direction();
        let slot = match direction {
            Playback::Forward => i,
            Playback::Reversed => per_direction + i,
        };
        let frames = TargetFrames::new(self.frames.len(), direction, i);
        self.targets[slot].get_or_init(|| PreparedTarget::compute(&self.frames, frames)).as_ref()
    }
}

enum Slot {
    /// Some thread is loading the clip; others wait on [`ClipCache::changed`].
    Loading,
    Ready(Arc<LoadedClip>),
}

/// Loaded clips by id.
#[derive(Default)]
pub(crate) struct ClipCache {
    slots: Mutex<HashMap<u64, Slot>>,
    changed: Condvar,
}

impl ClipCache {
    fn lock(&self) -> MutexGuard<'_, HashMap<u64, Slot>> {
        // Loads run outside the lock and panics are caught by the workers: a poisoned map is still consistent.
        self.slots.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Clip `id`, loading it with `load` unless it is cached or being loaded by another thread
    /// (then this one waits). Errors are not cached: the next caller tries again.
    pub fn get_or_load(&self, id: u64, load: impl FnOnce() -> Result<LoadedClip>) -> Result<Arc<LoadedClip>> {
        let mut slots = self.lock();
        loop {
            match slots.get(&id) {
                Some(Slot::Ready(clip)) => return Ok(clip.clone()),
                Some(Slot::Loading) => slots = self.changed.wait(slots).unwrap_or_else(PoisonError::into_inner),
                None => break,
            }
        }
        slots.insert(id, Slot::Loading);
        drop(slots);
        self.load_claimed(id, load)
    }

    /// Loads clip `id` unless it is cached or being loaded; never waits for another thread.
    /// `None` if there was nothing to do.
    pub fn load_if_absent(&self, id: u64, load: impl FnOnce() -> Result<LoadedClip>) -> Option<Result<()>> {
        {
            let mut slots = self.lock();
            if slots.contains_key(&id) {
                return None;
            }
            slots.insert(id, Slot::Loading);
        }
        Some(self.load_claimed(id, load).map(|_| ()))
    }

    /// Loads a clip whose slot this thread has set to `Loading`, and publishes the result.
    fn load_claimed(&self, id: u64, load: impl FnOnce() -> Result<LoadedClip>) -> Result<Arc<LoadedClip>> {
        /// Wakes the waiters when the load ends, and frees the slot if the load failed or
        /// panicked, so that nobody waits forever.
        struct Claim<'a> {
            cache: &'a ClipCache,
            id: u64,
            published: bool,
        }
        impl Drop for Claim<'_> {
            fn drop(&mut self) {
                if !self.published {
                    self.cache.lock().remove(&self.id);
                }
                self.cache.changed.notify_all();
            }
        }
        let mut claim = Claim { cache: self, id, published: false };
        let clip = Arc::new(load()?);
        self.lock().insert(id, Slot::Ready(clip.clone()));
        claim.published = true;
        Ok(clip)
    }

    /// Drops every loaded clip for which `keep(id)` is false (clips being loaded stay; users of a
    /// dropped clip keep their `Arc`).
    pub fn retain(&self, keep: impl Fn(u64) -> bool) {
        self.lock().retain(|&id, slot| matches!(slot, Slot::Loading) || keep(id));
    }

    pub fn contains(&self, id: u64) -> bool {
        self.lock().contains_key(&id)
    }

    /// The ids of loaded clips, sorted.
    #[cfg(test)]
    pub fn loaded_ids(&self) -> Vec<u64> {
        let mut ids: Vec<u64> =
            self.lock().iter().filter_map(|(&id, slot)| matches!(slot, Slot::Ready(_)).then_some(id)).collect();
        ids.sort_unstable();
        ids
    }
}
