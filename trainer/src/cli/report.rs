//! `s3tir-train report RUN`: the run report written again (for a run that predates it, or after
//! its dataset moved back into place); training writes it at the end of every run.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use s3tir_trainer::dataset::Dataset;
use s3tir_trainer::look::LookError;
use s3tir_trainer::look::report::{ReportWritten, write_report_for, write_run_report};
use s3tir_trainer::train::TrainConfig;

/// Options of `s3tir-train report`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    /// Run folder written by training (its config.json, eval.json, renders/ and gbuffers/;
    /// the dataset named in config.json gives the recorded frames).
    pub run_dir: PathBuf,
}

/// `report`: writes RUN/report.html, RUN/report.md and RUN/report/*.png; prints the page's
/// path and what it could not show.
pub fn run(a: &ReportArgs) -> Result<()> {
    let written = write_report(&a.run_dir)?;
    println!("{}", written.display());
    Ok(())
}

/// Writes the report of `run_dir` with a progress bar over its held-out views; says what it
/// could not show on stderr and returns the HTML page's path.
pub fn write_report(run_dir: &Path) -> Result<PathBuf> {
    with_bar(run_dir, &mut |on_view| write_run_report(run_dir, on_view))
}

/// The report at the end of a training run, from the trainer's configuration and dataset.
pub fn write_report_after_training(
    run_dir: &Path,
    cfg: &TrainConfig,
    data: &Dataset,
) -> Result<PathBuf> {
    with_bar(run_dir, &mut |on_view| {
        write_report_for(run_dir, cfg, Ok(data), on_view)
    })
}

type Writer<'a> = dyn FnMut(&mut dyn FnMut(usize, usize)) -> Result<ReportWritten, LookError> + 'a;

fn with_bar(run_dir: &Path, write: &mut Writer<'_>) -> Result<PathBuf> {
    // A bar over the held-out views (indicatif draws it only when stderr is a terminal).
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("report [{bar:30}] {pos}/{len} views")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let written = write(&mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("writing the report of {}", run_dir.display()))?;
    bar.finish_and_clear();
    for m in &written.missing {
        eprintln!("report: {m}");
    }
    Ok(written.html)
}
