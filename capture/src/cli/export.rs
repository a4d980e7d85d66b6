//! `s3tir-capture export`: a session's pairs in the board-folder layout (`--out`), and a posed
//! dataset (`--dataset`) made by the `s3tir-calib poses` process beside this program.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use s3tir_capture::tools;

use super::progress_spinner;

/// Options of `s3tir-capture export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    file: PathBuf,
    /// Board-folder layout of the pairs.
    #[arg(long, required_unless_present = "dataset")]
    out: Option<PathBuf>,
    /// Posed dataset for s3tir-train (needs the rig's calibration).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// The rig's calibration.yaml for --dataset [default: the one attached to the session].
    #[arg(long, requires = "dataset")]
    calibration: Option<PathBuf>,
    /// AprilTag map for --dataset (s3tir-calib poses --tags): metric scale, and poses
    /// without COLMAP where mapped tags are in view.
    #[arg(long, requires = "dataset")]
    tags: Option<PathBuf>,
    /// The calibration board standing in the scene, for --dataset (s3tir-calib poses
    /// --board): metric scale, and poses without COLMAP where it is in view.
    #[arg(long, requires = "dataset", conflicts_with = "tags")]
    board: Option<PathBuf>,
    /// With --tags or --board: run COLMAP anyway (the fiducials then give the metric scale
    /// and check COLMAP's model; s3tir-calib poses --no-tag-poses).
    #[arg(long)]
    no_tag_poses: bool,
    /// The dataset also holds the posed RGB keyframes (a second camera, poses in the
    /// thermal views' world) for joint RGB + thermal training (s3tir-calib poses
    /// --with-rgb); an error on a session without RGB.
    #[arg(long, requires = "dataset")]
    with_rgb: bool,
    /// Print one JSON object (pairs exported, the dataset folder and its poses.json);
    /// s3tir-calib poses' own output then goes to stderr.
    #[arg(long)]
    json: bool,
}

/// Runs `export`.
pub fn run(a: &ExportArgs) -> Result<()> {
    let file = &a.file;
    let json = a.json;
    let mut summary = serde_json::json!({ "session": file });
    if let Some(out) = &a.out {
        let bar = progress_spinner("exported {pos} pairs");
        let n = tools::export_with_progress(file, out, |k| bar.set_position(k))?;
        bar.finish_and_clear();
        if json {
            summary["board_folder"] = serde_json::json!({ "dir": out, "pairs": n });
        } else {
            println!("exported {n} pairs to {}", out.display());
        }
    }
    if let Some(dataset) = &a.dataset {
        let opts = PosesOptions {
            calibration: a.calibration.as_deref(),
            tags: a.tags.as_deref(),
            board: a.board.as_deref(),
            no_tag_poses: a.no_tag_poses,
            with_rgb: a.with_rgb,
            json,
        };
        export_dataset(file, dataset, &opts)?;
        if json {
            summary["dataset"] = serde_json::json!({
                "dir": dataset,
                "report": dataset.join("poses.json"),
            });
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(())
}

/// The `export --dataset` options passed on to `s3tir-calib poses`.
struct PosesOptions<'a> {
    calibration: Option<&'a Path>,
    tags: Option<&'a Path>,
    board: Option<&'a Path>,
    no_tag_poses: bool,
    with_rgb: bool,
    /// Our stdout carries one JSON object: the child's stdout goes to stderr.
    json: bool,
}

/// `export --dataset`: capture sits below calib (ARCHITECTURE.md), so the poses stage runs as
/// the `s3tir-calib poses` process installed beside this program.
fn export_dataset(session: &Path, dataset: &Path, opts: &PosesOptions<'_>) -> Result<()> {
    let PosesOptions {
        calibration,
        tags,
        board,
        no_tag_poses,
        with_rgb,
        json,
    } = *opts;
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .unwrap_or_default();
    let calib = exe_dir.join("s3tir-calib");
    if !calib.is_file() {
        bail!(
            "export --dataset runs s3tir-calib poses, and {} is not installed (build the workspace: cargo build --workspace --bins)",
            calib.display()
        );
    }
    let mut cmd = std::process::Command::new(&calib);
    cmd.arg("poses").arg(session).arg("--out").arg(dataset);
    if let Some(c) = calibration {
        cmd.arg("--calibration").arg(c);
    }
    if let Some(t) = tags {
        cmd.arg("--tags").arg(t);
    }
    if let Some(b) = board {
        cmd.arg("--board").arg(b);
    }
    if no_tag_poses {
        cmd.arg("--no-tag-poses");
    }
    if with_rgb {
        cmd.arg("--with-rgb");
    }
    if json {
        cmd.stdout(std::io::stderr());
    }
    let status = cmd
        .status()
        .with_context(|| format!("running {}", calib.display()))?;
    if !status.success() {
        bail!(
            "s3tir-calib poses failed ({status}): no dataset written to {}",
            dataset.display()
        );
    }
    Ok(())
}
