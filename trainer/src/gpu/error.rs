//! Errors of the Vulkan backend. Every variant names the device, call, buffer or feature.

use ash::vk;

/// Errors raised by the Vulkan backend.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// The Vulkan loader library could not be loaded.
    #[error(
        "no Vulkan loader (install a loader and a driver; Debian: libvulkan1 and \
         mesa-vulkan-drivers, which includes the lavapipe CPU driver)"
    )]
    LoaderMissing {
        #[source]
        source: ash::LoadingError,
    },
    /// The loader runs but offers no physical device.
    #[error(
        "the Vulkan loader found no device; install a driver (Debian: mesa-vulkan-drivers \
         provides lavapipe) or check VK_ICD_FILENAMES"
    )]
    NoDevice,
    /// A Vulkan call returned an error.
    #[error("Vulkan {call} failed: {result}")]
    Vk {
        call: &'static str,
        result: vk::Result,
    },
    /// The requested device index does not exist.
    #[error(
        "device index {index} out of range: {count} Vulkan device(s) (list them with `s3tir-train devices`)"
    )]
    DeviceIndexOutOfRange { index: usize, count: usize },
    /// No device matched the requested name.
    #[error("no Vulkan device name contains {pattern:?} (list them with `s3tir-train devices`)")]
    NoDeviceNamed { pattern: String },
    /// The device lacks something the requested work needs.
    #[error("Vulkan device {device:?} lacks {feature}")]
    MissingFeature { device: String, feature: String },
    /// A device limit is below what the requested work needs.
    #[error("Vulkan device {device:?}: {limit} is {actual}, {required} needed")]
    LimitTooSmall {
        device: String,
        limit: &'static str,
        required: u64,
        actual: u64,
    },
    /// A buffer a run of this primitive budget needs exceeds a device limit (checked before
    /// training starts).
    #[error(
        "Vulkan device {device:?}: a budget of {budget} primitives with {bands} bands needs \
         buffer {buffer} of {required} {unit}, above its {limit} of {actual}: lower --budget or \
         --bands, or train on a device with a larger limit"
    )]
    BudgetTooLarge {
        device: String,
        buffer: &'static str,
        budget: usize,
        bands: usize,
        limit: &'static str,
        /// What `required` and `actual` count (`bytes`, `texels`).
        unit: &'static str,
        required: u64,
        actual: u64,
    },
    /// gpu-allocator could not provide memory.
    #[error("GPU memory for {name} ({bytes} bytes)")]
    Allocation {
        name: String,
        bytes: u64,
        #[source]
        source: gpu_allocator::AllocationError,
    },
    /// A lock of the context (the memory allocator, a buffer pool) was poisoned by a panic in
    /// another thread: what it guards is in an unknown state.
    #[error("{what}: its lock was poisoned by a panic in another thread")]
    LockPoisoned { what: &'static str },
    /// A shader is unknown, or a kernel's use does not match its interface.
    #[error("shader {name}: {reason}")]
    Shader { name: String, reason: String },
    /// A shader's SPIR-V module is malformed.
    #[error("shader {name}: malformed SPIR-V")]
    MalformedSpirv {
        name: String,
        #[source]
        source: std::io::Error,
    },
    /// The driver refused to build a shader's module or pipeline.
    #[error("shader {name}: {call}")]
    ShaderBuild {
        name: String,
        call: &'static str,
        #[source]
        source: vk::Result,
    },
    /// Input data the GPU path cannot take (shapes, non-finite camera).
    #[error("invalid input: {reason}")]
    InvalidInput { reason: String },
    /// Primitives or a camera that the renderer's own checks refuse (boxed: the renderer's
    /// error also wraps this one).
    #[error("invalid input")]
    InvalidScene {
        #[source]
        source: Box<crate::error::RenderError>,
    },
    /// A host read or write does not fit a buffer.
    #[error("buffer {name}: {requested_bytes} bytes requested, it holds {capacity_bytes}")]
    BufferRange {
        name: String,
        requested_bytes: u64,
        capacity_bytes: u64,
    },
    /// A submission did not finish in time: a hung GPU or driver. Its resources are leaked
    /// (the device may still use them); the run stops with its last checkpoint intact.
    #[error(
        "Vulkan device {device:?} did not finish a submission in {waited_s:.0} s (hung GPU or \
         driver); stopping instead of waiting for ever"
    )]
    SubmitTimeout { device: String, waited_s: f64 },
}

/// Maps a `vk::Result` error of `call` into [`GpuError::Vk`].
pub(crate) fn vk_err(call: &'static str) -> impl Fn(vk::Result) -> GpuError {
    move |result| GpuError::Vk { call, result }
}
