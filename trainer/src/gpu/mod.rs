//! Vulkan compute through ash (feature `vulkan`).
//!
//! - [`devices`]: the Vulkan instance and what each device offers (`s3tir-train devices`),
//! - [`context`]: one device opened for compute, a file per job: opening it (`open`: device
//!   choice, up-front checks, features, queue and allocator), storage buffers (`buffers`:
//!   gpu-allocator memory with peak use, uploads and reads), compute kernels (`kernels`:
//!   pipelines and descriptor layouts), one-shot submissions (`submit`: bounded fence waits,
//!   timestamp queries) and what is recorded into them (`recorder`: dispatches, copies,
//!   barriers),
//! - [`error`]: [`GpuError`], naming the device, call, buffer or feature, with the driver's,
//!   loader's or allocator's error as its source,
//! - [`shaders`]: every GLSL kernel of `trainer/shaders/`, compiled to SPIR-V by glslc in build.rs,
//!   with the interface (bindings, push constants, required features) the host uses to run it,
//! - [`reduce`]: a parallel float sum, in a subgroup-arithmetic and a portable shared-memory
//!   variant chosen at run time from the device's capabilities,
//! - [`scan`], [`sort`]: exclusive prefix sum and stable 64-bit-key radix sort (tile binning and
//!   depth ordering of the rasteriser),
//! - [`accumulate`]: float scatter-add with `atomicAdd(float)` or a CAS-loop fallback,
//! - [`pool`]: reuse of released buffers (a warm training step allocates nothing; per-primitive
//!   buffers sized for the run's budget),
//! - [`raster`]: the forward rasteriser (projection + culling, binning, sort, per-tile blend of
//!   the thermal image, the G-buffers and, for primitives with an SH colour, the RGB planes) and
//!   its exact backward pass, held to the CPU reference renderer by parity tests,
//! - [`loss`]: the single-view loss (L1 + D-SSIM, sparsity, TV) and its gradient,
//! - [`consistency`]: the multi-view frequency consistency term and its gradients,
//! - [`optimiser`]: parameters, Adam moments and densification statistics resident on the GPU,
//!   and the Adam kernel (the host optimiser's rules),
//! - [`backend`]: the training loop's `Backend` on the GPU (`s3tir-train --backend vulkan`),
//! - [`bench`](mod@bench): `s3tir-train bench`, Vulkan vs CPU steps/s and the per-kernel breakdown.
//!
//! Devices without a feature get a typed [`GpuError`] naming it, checked when the context opens
//! or when a kernel that needs it is created, never a driver crash mid-run.

pub mod accumulate;
pub mod backend;
pub mod bench;
pub mod consistency;
pub mod context;
pub mod devices;
pub mod error;
pub mod loss;
pub mod optimiser;
pub mod pool;
pub mod raster;
pub mod reduce;
pub mod scan;
pub mod shaders;
pub mod sort;

pub use context::{
    Binding, Capabilities, ComputeKernel, ContextOptions, DeviceChoice, GpuBuffer, GpuContext,
    KernelTiming, MemoryLocation, Recorder, TexelFormat,
};
pub use devices::{DeviceReport, VulkanInstance};
pub use error::GpuError;
