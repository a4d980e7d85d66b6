//! `s3tir-train compare`: several runs' error-vs-time curves on one plot.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use s3tir_trainer::report;
use s3tir_trainer::train::{self, files};

/// Options of `s3tir-train compare`.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// Run folders.
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(long, default_value = "compare.png")]
    pub out: PathBuf,
}

/// `compare`: prints each run's last metrics row and writes the plot.
pub fn run(a: &CompareArgs) -> Result<()> {
    let (runs, out) = (&a.runs, &a.out);
    let mut series = Vec::new();
    for r in runs {
        let rows = report::read_rows(&r.join(files::METRICS_CSV))
            .with_context(|| format!("reading the metrics of {}", r.display()))?;
        let mode = train::load_config(r).map_or_else(|_| "?".to_owned(), |c| c.mode.to_string());
        let name = r.file_name().map_or_else(
            || r.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        if let Some(last) = rows.last() {
            println!(
                "{name:<20} {mode:<6} iter {:>6}  {:8.1} s  PSNR {:6.2} dB (aligned {})  SSIM {:.4}  MAE {}  {} primitives",
                last.iteration,
                last.seconds,
                last.psnr,
                last.psnr_aligned
                    .map_or_else(|| "—".into(), |v| format!("{v:.2} dB")),
                last.ssim,
                last.kelvin_mae
                    .map_or_else(|| "—".into(), |v| format!("{v:.3} K")),
                last.primitives
            );
        }
        series.push((format!("{name} ({mode})"), rows));
    }
    report::plot_runs(out, &series).with_context(|| format!("plotting {}", out.display()))?;
    println!("plot: {}", out.display());
    Ok(())
}
