//! [`RenderError`]: errors of the renderer and of what runs on its buffers — parameter and
//! buffer shapes, cameras, SH degrees in the CPU reference renderer, the losses and the
//! optimiser, and the Vulkan backend's failures. The training run's own error (datasets,
//! checkpoints, outputs, configuration) is `train::TrainError`, which wraps this one.

use thiserror::Error;

/// A render, loss or optimiser computation failed (CPU reference or Vulkan backend).
#[derive(Debug, Error)]
pub enum RenderError {
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
