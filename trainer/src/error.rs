//! Errors of the CPU reference renderer, losses and optimiser.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum TrainerError {
    #[error("parameter group `{group}` has {actual} values, expected {expected}")]
    ParameterLength {
        group: &'static str,
        expected: usize,
        actual: usize,
    },
    #[error("buffer `{buffer}` has {actual} values, expected {expected} ({width}×{height})")]
    BufferSize {
        buffer: &'static str,
        width: usize,
        height: usize,
        expected: usize,
        actual: usize,
    },
    #[error("camera `{camera}` is invalid: {reason}")]
    InvalidCamera {
        camera: &'static str,
        reason: &'static str,
    },
    #[error("SH degree {degree} is not supported (at most {max})")]
    UnsupportedShDegree { degree: usize, max: usize },
    /// The Vulkan backend (the `gpu` module) failed; its error names the device and call.
    #[cfg(feature = "vulkan")]
    #[error(transparent)]
    Gpu {
        #[from]
        source: crate::gpu::GpuError,
    },
}
