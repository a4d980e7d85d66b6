//! The subcommands of `s3tir-train`, one module each (their options and what they run); the
//! binary's `main.rs` holds the clap top level, the logging set-up and the dispatch.
//!
//! - [`train`]: `s3tir-train DATA --out RUN_DIR` / `train`: a new or resumed run.
//! - [`train_summary`]: what a run prints when it ends (lines, or the `--json` object).
//! - [`train_args`]: the training options (shared with `ablation`) and the run configuration
//!   they make.
//! - `session` (feature `session`): a recorded session (`SESSION.mcap`) posed into a dataset
//!   before training.
//! - [`eval`]: `eval`: held-out metrics of a run, or its score against a simulated truth.
//! - [`ablation`]: `ablation`: the TGA-GS ablation's runs and table.
//! - [`bench`]: `bench`: training steps/s per backend, or the stages of meshing.
//! - [`mesh`]: `mesh`: a run fused into a surface mesh with kelvin per vertex.
//! - [`compare`]: `compare`: several runs' error-vs-time curves on one plot.
//! - [`report`]: `report`: the run report (`report.html`) written again.
//! - [`render`]: `render`: novel views along a path, palette frames and a video.
//! - [`view`]: `view`: the local web viewer of the run's thermal mesh.
//! - [`devices`]: `devices`: the Vulkan devices and what the trainer needs of them.
//! - [`synth`]: `synth`: the built-in analytic test scene as a COLMAP dataset.

/// A human-readable line: on stdout, or on stderr when stdout carries the `--json` summary.
macro_rules! say {
    ($json:expr, $($arg:tt)*) => {
        if $json {
            eprintln!($($arg)*)
        } else {
            println!($($arg)*)
        }
    };
}

pub mod ablation;
pub mod bench;
pub mod compare;
pub mod devices;
pub mod eval;
pub mod mesh;
pub mod render;
pub mod report;
#[cfg(feature = "session")]
pub mod session;
pub mod synth;
pub mod train;
pub mod train_args;
pub mod train_summary;
pub mod view;

/// `--backend auto`'s Vulkan backend: the best device, opened with the trainer's checks
/// (work-group sizes, storage-buffer room, every kernel built), and why it was taken; `Err`
/// says why there is none.
#[cfg(feature = "vulkan")]
pub fn open_auto(
    device_index: Option<usize>,
    no_float_atomics: bool,
) -> std::result::Result<(s3tir_trainer::gpu::backend::VulkanBackend, String), String> {
    match s3tir_trainer::gpu::backend::VulkanBackend::new(
        &vulkan_options(device_index, no_float_atomics),
        s3tir_trainer::render::RenderSettings::default(),
    ) {
        Ok(b) => {
            let why = format!("{} passes the trainer's checks", b.context().report().name);
            Ok((b, why))
        }
        Err(e) => Err(format!(
            "no Vulkan device passes the trainer's checks: {}",
            s3tir_capture::Chain(&e)
        )),
    }
}

/// What `--backend auto` takes on this machine and why (the Vulkan backend is opened to check,
/// then closed).
#[cfg(feature = "vulkan")]
pub fn auto_backend(
    device_index: Option<usize>,
    no_float_atomics: bool,
) -> (s3tir_trainer::train::BackendKind, String) {
    use s3tir_trainer::train::BackendKind;
    match open_auto(device_index, no_float_atomics) {
        Ok((_, why)) => (BackendKind::Vulkan, why),
        Err(why) => (BackendKind::Cpu, why),
    }
}

/// Without the `vulkan` feature `--backend auto` is the CPU.
#[cfg(not(feature = "vulkan"))]
pub fn auto_backend(_: Option<usize>, _: bool) -> (s3tir_trainer::train::BackendKind, String) {
    (
        s3tir_trainer::train::BackendKind::Cpu,
        "this s3tir-train was built without the `vulkan` feature".into(),
    )
}

/// The Vulkan context options of `--device-index` and `--no-float-atomics`.
#[cfg(feature = "vulkan")]
pub fn vulkan_options(
    device_index: Option<usize>,
    no_float_atomics: bool,
) -> s3tir_trainer::gpu::ContextOptions {
    use s3tir_trainer::gpu::{ContextOptions, DeviceChoice};
    ContextOptions {
        device: device_index.map_or(DeviceChoice::Best, DeviceChoice::Index),
        disable_float_atomics: no_float_atomics,
    }
}
