//! `s3tir-train SESSION.mcap` and `s3tir-train IMAGES_DIR`: a recorded session, or a folder of
//! thermal images, posed into a dataset before training (calib's poses stages, in-process).

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

use super::train_args::TrainArgs;

/// Where a posed input's dataset goes: `--dataset`, else `RUN_DIR-dataset` beside the run; the
/// run itself must not exist yet.
fn dataset_dir(a: &TrainArgs, out: &Path) -> Result<PathBuf> {
    if out.exists() {
        bail!(
            "{} exists: s3tir-train never overwrites a run (choose another --out)",
            out.display()
        );
    }
    Ok(a.dataset.clone().unwrap_or_else(|| {
        let mut name = out.file_name().unwrap_or_default().to_os_string();
        name.push("-dataset");
        out.with_file_name(name)
    }))
}

/// Whether `dir` is a folder of images to pose (not a dataset: no `sparse/`; images in it or a
/// `thermal/` subfolder).
pub fn is_image_folder(dir: &Path) -> bool {
    if !dir.is_dir() || dir.join("sparse").exists() {
        return false;
    }
    dir.join("thermal").is_dir()
        || std::fs::read_dir(dir).is_ok_and(|rd| {
            rd.filter_map(|e| e.ok()).any(|e| {
                e.path()
                    .extension()
                    .and_then(|x| x.to_str())
                    .is_some_and(|x| {
                        ["jpg", "jpeg", "tif", "tiff", "png", "fff"]
                            .contains(&x.to_ascii_lowercase().as_str())
                    })
            })
        })
}

/// `s3tir-train IMAGES_DIR`: the folder stage (calib's, in-process) writes the dataset first.
pub fn pose_folder(a: &TrainArgs, dir: &Path, out: &Path) -> Result<PathBuf> {
    use s3tir_calib::model::calfile::CalibrationFile;
    use s3tir_calib::poses::folder::{self, FolderOptions, intrinsics::IntrinsicsArgs};
    let dataset = dataset_dir(a, out)?;
    let calibration = match &a.posing.calibration {
        Some(p) => Some((p.clone(), CalibrationFile::read(p)?)),
        None => None,
    };
    let opts = FolderOptions {
        holdout_every: a.holdout,
        progress: Some(std::sync::Arc::new(
            s3tir_calib::progress::bars::ProgressBars::new(),
        )),
        ..a.folder.options(
            IntrinsicsArgs {
                calibration,
                ..IntrinsicsArgs::default()
            },
            &a.posing.options(),
        )
    };
    println!(
        "posing the images of {} into {}",
        dir.display(),
        dataset.display()
    );
    // No context added: the stage's errors name the folder or file they are about.
    let report = folder::folder_to_dataset(dir, &dataset, &opts)?;
    print!("{}", folder::summary(&report));
    Ok(dataset)
}

/// `s3tir-train SESSION.mcap`: the poses stage (calib's, in-process) writes the dataset first.
pub fn pose_session(a: &TrainArgs, session: &Path, out: &Path) -> Result<PathBuf> {
    use s3tir_calib::model::calfile::CalibrationFile;
    use s3tir_calib::poses::{self, PosesOptions};
    let dataset = dataset_dir(a, out)?;
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
