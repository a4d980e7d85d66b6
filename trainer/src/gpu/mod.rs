//! Vulkan compute through ash (feature `vulkan`).
//!
//! - [`devices`]: the Vulkan instance and what each device offers (`s3tir-train devices`),
//! - [`context`]: one device opened for compute: queue, memory (gpu-allocator, with peak use),
//!   storage buffers, compute kernels, one-shot submissions,
//! - [`shaders`]: every GLSL kernel of `trainer/shaders/`, compiled to SPIR-V by glslc in build.rs,
//!   with the interface (bindings, push constants, required features) the host uses to run it,
//! - [`reduce`]: a parallel float sum, in a subgroup-arithmetic and a portable shared-memory
//!   variant chosen at run time from the device's capabilities.
//!
//! Devices without a feature get a typed [`GpuError`] naming it, checked when the context opens
//! or when a kernel that needs it is created, never a driver crash mid-run.

pub mod context;
pub mod devices;
pub mod error;
pub mod reduce;
pub mod shaders;

pub use context::{
    Capabilities, ComputeKernel, DeviceChoice, GpuBuffer, GpuContext, MemoryLocation,
};
pub use devices::{DeviceReport, VulkanInstance};
pub use error::GpuError;
