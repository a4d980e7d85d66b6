//! The S³-TIR ablation (paper Table 2) on one thermal dataset: the full method and each of its
//! parts taken away — shape control (β ≡ 2), spectral modulation (f = 0), the consistency term,
//! the sparsity term — with plain Gaussians (3dgs mode) as the baseline. Every run has the base
//! configuration's length (give a `--time-budget` and the rows compare at equal wall time, the
//! product's rule) and is scored on the dataset's held-out views as a run scores itself
//! (`eval.json`: PSNR, SSIM, LPIPS, kelvin error), so the table needs no truth and runs on
//! real sets too.
//!
//! "f = 0" is run as the ges mode (learnable β, no bands): a band of frequency zero is the
//! constant `ω_j·cos φ_j`, which the primitive's low-frequency value already carries, so the
//! paper's variant and a primitive without bands represent the same images.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use crate::metrics::EvalSummary;
use crate::train::{Backend, Event, Mode, TrainConfig, TrainError, files};

/// One configuration of the S³-TIR ablation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SpectralVariant {
    /// The full method (s3tir mode, the base configuration as given).
    Full,
    /// Without shape control: β ≡ 2 (the gabor mode: bands on a Gaussian).
    BetaFixed,
    /// Without spectral modulation, f = 0 (the ges mode; see the module docs).
    NoSpectral,
    /// Without the multi-view frequency consistency term.
    NoConsist,
    /// Without the sparsity prior.
    NoSparse,
    /// Plain 3D Gaussian splatting, the baseline.
    Gaussian,
}

impl SpectralVariant {
    pub const ALL: [SpectralVariant; 6] = [
        SpectralVariant::Full,
        SpectralVariant::BetaFixed,
        SpectralVariant::NoSpectral,
        SpectralVariant::NoConsist,
        SpectralVariant::NoSparse,
        SpectralVariant::Gaussian,
    ];

    /// Folder name of the variant's run.
    pub fn slug(self) -> &'static str {
        match self {
            SpectralVariant::Full => "s3tir",
            SpectralVariant::BetaFixed => "beta-fixed",
            SpectralVariant::NoSpectral => "no-spectral",
            SpectralVariant::NoConsist => "no-consist",
            SpectralVariant::NoSparse => "no-sparse",
            SpectralVariant::Gaussian => "3dgs",
        }
    }

    /// The row's label in the table (the paper's wording).
    pub fn label(self) -> &'static str {
        match self {
            SpectralVariant::Full => "S³-TIR (full)",
            SpectralVariant::BetaFixed => "w/o shape control (β = 2)",
            SpectralVariant::NoSpectral => "w/o spectral modulation (f = 0)",
            SpectralVariant::NoConsist => "w/o consistency loss",
            SpectralVariant::NoSparse => "w/o sparsity prior",
            SpectralVariant::Gaussian => "3DGS (baseline)",
        }
    }

    /// The variant's configuration derived from the full method's `base` (its mode is set to
    /// s3tir whatever `base` says).
    pub fn config(self, base: &TrainConfig) -> TrainConfig {
        let mut c = base.clone();
        c.mode = Mode::S3tir;
        match self {
            SpectralVariant::Full => {}
            SpectralVariant::BetaFixed => c.mode = Mode::Gabor,
            SpectralVariant::NoSpectral => c.mode = Mode::Ges,
            SpectralVariant::NoConsist => c.consist = false,
            SpectralVariant::NoSparse => c.sparse = false,
            SpectralVariant::Gaussian => c.mode = Mode::Gaussian,
        }
        c
    }
}

/// One row of the table: the run and its held-out figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpectralRow {
    pub variant: SpectralVariant,
    pub run_dir: PathBuf,
    pub iterations: u64,
    pub train_seconds: f64,
    pub primitives: usize,
    /// Primitives holding a live band at the end.
    pub band_holders: usize,
    /// The run's `eval.json`, as written.
    pub eval: EvalSummary,
}

/// Trains every variant of `base` into `out/<slug>` and reads back each run's `eval.json`;
/// `backend` makes each run's backend; `on_event` sees every run's events with its variant.
pub fn run_spectral_ablation<B: Backend>(
    base: &TrainConfig,
    out: &Path,
    backend: &mut dyn FnMut() -> Result<B, TrainError>,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(SpectralVariant, &Event),
) -> Result<Vec<SpectralRow>, TrainError> {
    let mut rows = Vec::new();
    for v in SpectralVariant::ALL {
        let dir = out.join(v.slug());
        let t = super::train_variant(v.config(base), dir.clone(), backend()?, stop, &mut |e| {
            on_event(v, e)
        })?;
        let path = dir.join(files::EVAL);
        let text = std::fs::read_to_string(&path).map_err(|source| TrainError::Io {
            path: path.clone(),
            source,
        })?;
        let eval =
            serde_json::from_str(&text).map_err(|source| TrainError::Json { path, source })?;
        rows.push(SpectralRow {
            variant: v,
            run_dir: dir,
            iterations: t.iteration,
            train_seconds: t.train_seconds,
            primitives: t.prims.len(),
            band_holders: t.capacity_report().band_holders,
            eval,
        });
    }
    Ok(rows)
}

/// The table as Markdown (paper Table 2's columns, with kelvin error, steps and primitives).
pub fn spectral_markdown(rows: &[SpectralRow]) -> String {
    let mut s = String::from(
        "| run | PSNR | SSIM | LPIPS | kelvin MAE | PSNR aligned | steps | seconds | primitives | band holders |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
    );
    // "—" where the run has no such figure (no LPIPS weights, non-radiometric data).
    let opt = |x: Option<f64>, digits: usize, unit: &str| {
        x.map_or_else(|| "—".to_owned(), |v| format!("{v:.digits$}{unit}"))
    };
    for r in rows {
        let e = &r.eval;
        s.push_str(&format!(
            "| {} | {:.2} dB | {:.3} | {} | {} | {} | {} | {:.0} | {} | {} |\n",
            r.variant.label(),
            e.psnr,
            e.ssim,
            opt(e.lpips, 3, ""),
            opt(e.kelvin_mae, 3, " K"),
            opt(e.psnr_aligned, 2, " dB"),
            r.iterations,
            r.train_seconds,
            r.primitives,
            r.band_holders,
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_variant_takes_away_its_own_part_only() {
        let mut base = TrainConfig::new("data".into());
        base.mode = Mode::Gaussian; // the ablation's base is the full method whatever is given
        let full = SpectralVariant::Full.config(&base);
        assert_eq!(full.mode, Mode::S3tir);
        assert!(full.consist && full.sparse);
        let differs = |v: SpectralVariant| {
            let c = v.config(&base);
            (
                c.mode != full.mode,
                c.consist != full.consist,
                c.sparse != full.sparse,
            )
        };
        assert_eq!(differs(SpectralVariant::BetaFixed), (true, false, false));
        assert_eq!(SpectralVariant::BetaFixed.config(&base).mode, Mode::Gabor);
        assert_eq!(SpectralVariant::NoSpectral.config(&base).mode, Mode::Ges);
        assert_eq!(differs(SpectralVariant::NoConsist), (false, true, false));
        assert_eq!(differs(SpectralVariant::NoSparse), (false, false, true));
        assert_eq!(SpectralVariant::Gaussian.config(&base).mode, Mode::Gaussian);
    }
}
