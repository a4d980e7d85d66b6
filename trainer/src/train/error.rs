//! The training loop's error type.

use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::checkpoint::CheckpointError;
use crate::dataset::DatasetError;
use crate::error::RenderError;
use crate::ply::PlyError;
use crate::report::ReportError;

#[derive(Debug, Error)]
pub enum TrainError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Ply(#[from] PlyError),
    #[error(transparent)]
    Report(#[from] ReportError),
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A JSON file of the run (`config.json`, `eval.json`, …) could not be read or written.
    #[error("{path}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// A stage run with the model (meshing, reading a truth surface) failed; `what` says
    /// which, the source why.
    #[error("{what}")]
    Stage {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A checkpoint's loop state (warm-up end, capacity decisions, responses) does not read.
    #[error(
        "{path}: the loop state does not read (a damaged checkpoint, or one from another \
         version of s3tir): not resumed, nothing changed; start a new run with another --out"
    )]
    CheckpointState {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("configuration: {reason}")]
    Config { reason: String },
    #[error("run {run_dir}: {reason}")]
    Run { run_dir: PathBuf, reason: String },
    /// A step's loss is NaN or infinite: the run stops before anything is saved from it.
    #[error(
        "run {run_dir}: iteration {iteration}: the loss is {loss} (the run diverged); stopped \
         without saving this state: the last checkpoint is intact, `--resume` continues from it \
         (lower the learning rates if it recurs)"
    )]
    NonFinite {
        run_dir: PathBuf,
        iteration: u64,
        loss: f64,
    },
}

pub(super) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}
