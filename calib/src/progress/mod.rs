//! Progress events of the library's long runs (detection over a folder or session, the
//! session scan of the poses stage, the real-set benchmark): the library emits them, the
//! binaries draw them (calib's and the trainer's through the adapter [`bars`], feature `poses`,
//! which no other library module uses).
//!
//! Thread-safe: detection reports from rayon's workers.

#[cfg(feature = "poses")]
pub mod bars;

use std::sync::Arc;

/// Receives a run's progress. Every method defaults to doing nothing.
pub trait Progress: Send + Sync + std::fmt::Debug {
    /// A stage begins: `stage` names it in words, `total` is its item count when known
    /// (`None`: a count without an end, e.g. frames of a session read once).
    fn start(&self, _stage: &str, _total: Option<u64>) {}
    /// `n` more items of the current stage are done.
    fn advance(&self, _n: u64) {}
    /// The item being worked on (e.g. a file name).
    fn item(&self, _name: &str) {}
    /// The current stage is over.
    fn finish(&self) {}
}

/// Progress nobody watches.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoProgress;

impl Progress for NoProgress {}

/// The receiver an options struct names, or [`NoProgress`] when it names none.
pub fn or_silent(progress: &Option<Arc<dyn Progress>>) -> &dyn Progress {
    match progress {
        Some(p) => p.as_ref(),
        None => &NoProgress,
    }
}
