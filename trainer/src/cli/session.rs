//! `s3tir-train SESSION.mcap`: a recorded session posed into a dataset before training.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

use super::train_args::TrainArgs;

/// `s3tir-train SESSION.mcap`: the poses stage (calib's, in-process) writes the dataset first.
pub fn pose_session(a: &TrainArgs, session: &Path, out: &Path) -> Result<PathBuf> {
    use s3tir_calib::model::calfile::CalibrationFile;
    use s3tir_calib::poses::{self, PosesOptions};
    if out.exists() {
        bail!(
            "{} exists: s3tir-train never overwrites a run (choose another --out)",
            out.display()
        );
    }
    let dataset = a.dataset.clone().unwrap_or_else(|| {
        let mut name = out.file_name().unwrap_or_default().to_os_string();
        name.push("-dataset");
        out.with_file_name(name)
    });
    let cal = match &a.posing.calibration {
        Some(p) => Some(CalibrationFile::read(p)?),
        None => None,
    };
    let opts = PosesOptions {
        holdout_every: a.holdout,
        progress: Some(std::sync::Arc::new(
            s3tir_calib::progress::bars::ProgressBars::new(),
        )),
        ..a.posing.options()
    };
    println!(
        "posing session {} into {}",
        session.display(),
        dataset.display()
    );
    // No context added: the stage's errors name the session or file they are about.
    let report = poses::session_to_dataset(session, cal.as_ref(), &dataset, &opts)?;
    print!("{}", poses::summary(&report));
    Ok(dataset)
}
