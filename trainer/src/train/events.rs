//! What the loop reports as it goes, and how a run ended.

use crate::report::MetricsRow;

/// What the loop reports as it goes (the CLI draws it).
#[derive(Debug, Clone)]
pub enum Event {
    Step {
        iteration: u64,
        loss: f64,
        /// Training seconds so far.
        seconds: f64,
        primitives: usize,
    },
    Eval(MetricsRow),
    Checkpoint {
        iteration: u64,
    },
}

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Finished,
    /// Stopped by the stop flag after writing a checkpoint.
    Interrupted {
        iteration: u64,
    },
}
