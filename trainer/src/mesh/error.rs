//! The mesh extraction's error type: every variant names the file, the count or the setting
//! that failed.

use std::path::PathBuf;

use thiserror::Error;

use crate::train::TrainError;

impl From<s3tir_calib::model::ply::FormatError> for MeshError {
    fn from(e: s3tir_calib::model::ply::FormatError) -> Self {
        MeshError::Ply {
            path: e.path,
            reason: e.reason,
        }
    }
}

#[derive(Debug, Error)]
pub enum MeshError {
    #[error("cannot write or read {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A malformed or unexpected PLY file (or a mesh that cannot be written as one).
    #[error("{path}: {reason}")]
    Ply { path: PathBuf, reason: String },
    /// A number of a PLY header that does not parse.
    #[error("{path}: {what}")]
    PlyNumber {
        path: PathBuf,
        /// The header line and what it holds.
        what: String,
        #[source]
        source: std::num::ParseFloatError,
    },
    /// Fewer views than the fusion needs.
    #[error("{views} views with a surface; meshing needs at least {required}")]
    TooFewViews { views: usize, required: usize },
    /// No pixel of any view renders opaque.
    #[error(
        "no pixel of the {views} rendered views reaches alpha {min_alpha}: there is no surface \
         to fuse (lower --min-alpha, or check the run)"
    )]
    NoOpaqueSurface { views: usize, min_alpha: f32 },
    /// Even the coarsest voxel tried does not fit the memory budget.
    #[error(
        "the surfaces touch at least {blocks} blocks at {voxel_m} m voxels, more than the \
         memory budget of {budget_bytes} bytes holds (raise --memory-budget-mib or \
         --voxel-size-m)"
    )]
    OverBudget {
        blocks: usize,
        budget_bytes: u64,
        voxel_m: f64,
    },
    /// Nothing to extract (no block, no zero crossing).
    #[error("nothing to extract: {reason}")]
    EmptyVolume { reason: String },
    /// A depth, temperature or colour buffer whose length is not the camera's pixel count.
    #[error(
        "frame of a {width}×{height} camera: {buffer} holds {actual} values, expected {expected}"
    )]
    FrameSize {
        width: usize,
        height: usize,
        buffer: &'static str,
        expected: usize,
        actual: usize,
    },
    /// Loading or rendering the run failed (the mesh command).
    #[error("mesh: {reason}")]
    Run { reason: String },
    #[error(transparent)]
    Train(#[from] TrainError),
}
