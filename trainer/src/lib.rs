//! s3tir-trainer: S³-TIR thermal splatting.
//!
//! - [`gpu`] (feature `vulkan`): Vulkan compute through ash — device discovery and reports,
//!   the compute context, and the kernels of the on-rig trainer.
//! - [`mesh`]: thermal mesh extraction — rendered views fused into a sparse TSDF, surface nets,
//!   a PLY with kelvin per vertex, the score against a simulated scene's truth surface.
//! - [`superres`]: super-resolved thermal — the K× render fused with the recorded image by
//!   back-projection.
//!
//! Conventions (frames, units, the paper's kernel without ½) are in `docs/CONVENTIONS.md`.

#[cfg(feature = "vulkan")]
pub mod gpu;

pub mod camera;
pub mod error;
pub mod loss;
pub mod primitive;
pub mod real;
pub mod render;
pub mod sh;

// Training pipeline (issue 7): datasets, PLY export, metrics, reports, checkpoints, the loop.
pub mod checkpoint;
pub mod dataset;
pub mod metrics;
pub mod ply;
pub mod report;
pub mod train;

// Joint RGB + thermal (TGA-GS): super-resolved thermal, scoring against a simulated scene's
// truth, the ablation table; thermal meshes.
pub mod ablation;
pub mod mesh;
pub mod superres;
pub mod truth;
