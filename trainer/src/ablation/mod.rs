//! Ablations run by one command (`s3tir-train ablation`): several runs of one base
//! configuration, each with one part of the method taken away, scored alike and written as
//! tables.
//! - [`tga`]: the TGA-GS ablation (paper Tables 3/4) on a joint RGB + thermal dataset with
//!   truth: thermal-only, joint, joint without alignment, joint without RGB pre-training, at
//!   equal iterations and at the joint run's training time.
//! - [`spectral`]: the S³-TIR ablation (paper Table 2) on any thermal dataset: the full method,
//!   β fixed, no spectral modulation, no consistency term, no sparsity term, and plain
//!   Gaussians, scored on the held-out views (PSNR, SSIM, LPIPS, kelvin error).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use crate::dataset::Dataset;
use crate::train::{Backend, Event, Outcome, TrainConfig, TrainError, Trainer};

pub mod spectral;
pub mod tga;

/// Trains one variant's run `cfg` into `dir` to its end on `backend`; an interrupted run is an
/// error (the table would be incomplete).
pub(crate) fn train_variant<B: Backend>(
    cfg: TrainConfig,
    dir: PathBuf,
    backend: B,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(&Event),
) -> Result<Trainer<B>, TrainError> {
    let data = Dataset::load(&cfg.data, &cfg.load)?;
    let mut t = Trainer::new(cfg, data, backend, &dir)?;
    if let Outcome::Interrupted { iteration } = t.run(stop, on_event)? {
        return Err(TrainError::Run {
            run_dir: dir,
            reason: format!("interrupted at iteration {iteration}: the table is incomplete"),
        });
    }
    Ok(t)
}

pub use spectral::SpectralVariant;
pub use tga::{AblationRow, Equal, RunLabel, Variant, markdown, run_ablation};
