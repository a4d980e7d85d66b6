//! s3tir-trainer: S³-TIR thermal splatting.
//!
//! - [`gpu`] (feature `vulkan`): Vulkan compute through ash — device discovery and reports,
//!   the compute context, and the kernels of the on-rig trainer.
//!
//! Conventions (frames, units, the paper's kernel without ½) are in `docs/CONVENTIONS.md`.

#[cfg(feature = "vulkan")]
pub mod gpu;
