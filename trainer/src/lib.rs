//! s3tir-trainer: S³-TIR thermal splatting.
//!
//! - [`camera`]: the pinhole camera the renderer projects through (from calib's model).
//! - [`primitive`]: the S³-TIR primitives (β, Gabor bands, SH colour) as parameter arrays.
//! - [`real`]: the float type the CPU renderer is generic over (f32/f64).
//! - [`sh`]: spherical harmonics of the colour head.
//! - [`render`]: the CPU reference renderer, forward and backward.
//! - [`loss`]: the losses and their gradients (photometric, consistency, regularisers,
//!   alignment, view response).
//! - [`error`]: [`error::RenderError`], errors of the renderer, losses, optimiser and Vulkan
//!   backend.
//! - [`dataset`]: COLMAP datasets (thermal and RGB views, hold-outs) loaded for training.
//! - [`train`]: the training loop, its configuration and its run errors (`TrainError`).
//! - [`checkpoint`]: checkpoints — a JSON header with the arrays in a safetensors file.
//! - [`ply`]: the primitives as a 3DGS-compatible PLY.
//! - [`metrics`]: PSNR, SSIM, LPIPS and kelvin errors of held-out views.
//! - [`installed`]: the data folder `scripts/install-deps.sh` installs into (LPIPS weights,
//!   the viewer's renderer).
//! - [`lpips`]: the LPIPS perceptual error (AlexNet, v0.1) on the CPU, from installed weights.
//! - [`report`]: metrics logs and plots of a run.
//! - [`look`]: what a person looks at — palette images with their range, figures with colour
//!   bars in kelvin and °C, the run report (`report.html`).
//! - [`compare`]: runs compared — repeated runs of a configuration as one mean-and-range curve,
//!   and where one configuration leads another after the warm-up.
//! - [`truth`]: a run scored against a simulated joint scene's truth.
//! - [`ablation`]: the TGA-GS ablation's runs and table.
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

// Training pipeline: datasets, PLY export, metrics, reports and comparisons, checkpoints, the
// loop.
pub mod checkpoint;
pub mod compare;
pub mod dataset;
pub mod installed;
pub mod look;
pub mod lpips;
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
