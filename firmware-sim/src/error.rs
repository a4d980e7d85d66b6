//! Errors of the simulated rig. Every variant names the file, profile or parameter it is about.

use std::path::PathBuf;

/// Errors raised by the simulator library.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("unknown profile {name:?}; known: {known}")]
    UnknownProfile { name: String, known: &'static str },
    #[error("{path}: {what}: {source}")]
    Io {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("encoding {what}: {reason}")]
    Encode { what: &'static str, reason: String },
    #[error("invalid parameter {parameter} = {value}: {why}")]
    InvalidParameter {
        parameter: &'static str,
        value: String,
        why: &'static str,
    },
    #[error("could not place view {view}: no board pose found after {attempts} attempts")]
    NoPose { view: usize, attempts: usize },
}
