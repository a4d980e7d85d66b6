//! Board folder → detections → per-camera OpenCV initialisation → one joint LM → result with
//! warnings. Detection and solving are separate steps ([`detect_folder`],
//! [`calibrate_detections`]) so the benchmark can time them apart.
//!
//! RMS figures follow OpenCV: `sqrt(Σ|r|² / N)` over corners (not per axis). The joint RMS
//! is over every inlier corner of both cameras (paired and unpaired views).
//!
//! This module runs the stages in order and builds the [`Calibration`]; each stage is a
//! module: `monos` (which cameras have enough views, OpenCV's initialisation of each, a mono
//! solve per camera and sub-pixel refinement, the refinement each keeps), `joint` (the pair
//! tests around the joint solve's rounds), `results` (the per-camera figures and the
//! warnings they call for); below them `init` (the per-camera OpenCV initialisation and the
//! model ↔ OpenCV conversions) and `solves` (a mono solve, the joint problem assembled from
//! the mono solves). The pair tests are [`crate::solve::pairs`], detection over a folder or
//! session [`crate::detect::views`].

mod init;
mod joint;
mod monos;
mod results;
mod solves;

use std::path::Path;
use std::sync::Arc;

use glam::DVec2;
use serde::Serialize;

use crate::detect::board::{BoardSpec, Camera, FileProblem};
use crate::detect::frontend::Refinement;
use crate::detect::session::SessionOptions;
pub use crate::detect::views::{
    DetectedSet, DetectedView, detect_folder, detect_session, detect_views, is_session,
};
use crate::error::CalibError;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::progress::{self, Progress};
use crate::solve::lm::{
    ExtrinsicSigma, IntrinsicSigma, IterationLog, RejectedCorner, SolveOptions,
};
use crate::solve::pairs::{InconsistentPair, PairThresholds};
pub use init::{INIT_VIEWS, ViewCorners, cv_points, model_from_opencv, opencv_k_dist};

/// Result for one camera.
#[derive(Debug, Clone, Serialize)]
pub struct CameraResult {
    pub camera: Camera,
    pub model: CameraModel,
    pub sigma: IntrinsicSigma,
    pub images: usize,
    pub views_found: usize,
    /// Of those, views found as a partial board around its AprilTags.
    pub views_partial: usize,
    pub views_used: usize,
    pub rms_px: f64,
    /// RMS over every detected corner including the rejected ones (px).
    pub rms_all_px: f64,
    /// OpenCV `calibrateCamera` RMS of the initialisation (px).
    pub init_rms_px: f64,
    /// This camera calibrated alone on its own views: RMS over inlier corners (px) ...
    pub mono_rms_px: f64,
    /// ... and over every detected corner (px; what OpenCV's `calibrateCamera` reports).
    pub mono_rms_all_px: f64,
    /// The sub-pixel refinement kept for this camera and why.
    pub refinement: Option<RefinementChoice>,
    /// Per view: (key, RMS px, inliers).
    pub per_view: Vec<ViewRms>,
}

/// A view's reprojection error for one camera.
#[derive(Debug, Clone, Serialize)]
pub struct ViewRms {
    pub key: String,
    pub rms_px: f64,
    pub corners_used: usize,
    pub tilt_deg: f64,
}

/// A corner residual for plots: observed position and residual (predicted − observed).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct CornerResidual {
    pub observed_px: DVec2,
    pub residual_px: DVec2,
    pub inlier: bool,
}

/// The calibration outcome.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    pub board: BoardSpec,
    pub cameras: [Option<CameraResult>; 2],
    pub rgb_from_thermal: Option<Rigid3>,
    pub extrinsic_sigma: Option<ExtrinsicSigma>,
    pub joint_rms_px: f64,
    pub pairs_used: usize,
    /// Pairs (views with the board in both cameras) before the consistency tests.
    pub pairs_found: usize,
    /// Pairs left out of the extrinsic, with their figures ([`crate::solve::pairs`]).
    pub pairs_inconsistent: Vec<InconsistentPair>,
    pub pair_thresholds: PairThresholds,
    pub warnings: Vec<String>,
    pub problems: Vec<FileProblem>,
    pub rejected: Vec<RejectedCorner>,
    pub iterations: Vec<IterationLog>,
    pub polarity_note: String,
    pub detection_wall_s: f64,
    pub solve_wall_s: f64,
    pub converged: bool,
    /// Per camera, every corner's residual (for the report's plots).
    #[serde(skip)]
    pub residuals: [Vec<CornerResidual>; 2],
    /// Keys of the views in solver order.
    pub view_keys: Vec<String>,
}

/// Options of a run.
#[derive(Debug, Clone, Default)]
pub struct PipelineOptions {
    pub solve: SolveOptions,
    /// Thresholds of the pair-consistency tests ([`crate::solve::pairs`]).
    pub pairs: PairThresholds,
    /// Receives detection's progress (`None`: nobody watches); the binary passes
    /// [`crate::progress::bars::ProgressBars`] to draw a bar.
    pub progress: Option<Arc<dyn Progress>>,
}

/// Which sub-pixel refinement a camera's corners use, and the figures that chose it.
#[derive(Debug, Clone, Serialize)]
pub struct RefinementChoice {
    pub kept: Refinement,
    /// Each refinement tried and the camera's mono RMS over every corner with it (px).
    pub mono_rms_all_px: Vec<(Refinement, f64)>,
}

/// Solves the detections of a folder.
pub fn calibrate_detections(
    set: &DetectedSet,
    opts: &PipelineOptions,
) -> Result<Calibration, CalibError> {
    let mut set = set.clone();
    let mut warnings = set.notes.clone();
    let object = set.board.object_points_m();
    // Each camera alone: which have enough views, their initialisation and mono solves, the
    // sub-pixel refinement each keeps.
    let (plans, found) = monos::plan_cameras(&set, object.len(), &mut warnings);
    let mut monos = monos::solve_monos(&mut set, &object, plans, &opts.solve)?;
    warnings.extend(
        std::mem::take(&mut monos.init_warnings)
            .into_iter()
            .flatten(),
    );
    if monos.mono.iter().all(Option::is_none) {
        return Err(nothing_usable(&set));
    }
    // Both together: the pair tests around the joint solve's rounds.
    let mut pairs = joint::transfer_pairs(&set, &object, &monos.mono, &opts.pairs);
    let joint = joint::joint_rounds(
        &set,
        &object,
        &monos.mono,
        &mut pairs,
        &opts.solve,
        &opts.pairs,
    );
    // The figures and what they warn about.
    let both = monos.mono.iter().all(Option::is_some);
    results::joint_warnings(both, &joint, &pairs, &mut warnings);
    let results = results::camera_results(&set, &joint, found, &monos, &mut warnings);
    for camera in Camera::BOTH {
        if set.images[camera.index()] == 0 {
            warnings.push(format!(
                "no {}/ images: calibrating the other camera alone",
                camera.name()
            ));
        }
    }
    Ok(Calibration {
        board: set.board.clone(),
        cameras: results.cameras,
        rgb_from_thermal: joint.problem.rgb_from_thermal,
        extrinsic_sigma: joint.report.extrinsic_sigma,
        joint_rms_px: results.joint_rms_px,
        pairs_used: joint.pairs_used,
        pairs_found: pairs.pair_views.len(),
        pairs_inconsistent: pairs.inconsistent,
        pair_thresholds: opts.pairs,
        warnings,
        problems: set.problems.clone(),
        rejected: joint.report.rejected,
        iterations: joint.report.iterations,
        polarity_note: set.polarity_note.clone(),
        detection_wall_s: set.detection_wall_s,
        solve_wall_s: joint.report.wall_s,
        converged: joint.report.converged,
        residuals: results.residuals,
        view_keys: joint.view_keys,
    })
}

/// The error when no camera could be calibrated: no images, or the first file problem.
fn nothing_usable(set: &DetectedSet) -> CalibError {
    let reason = if set.problems.is_empty() {
        "no images in thermal/ or rgb/".to_string()
    } else {
        format!(
            "{} file problems (first: {}: {})",
            set.problems.len(),
            set.problems[0].path.display(),
            set.problems[0].reason
        )
    };
    CalibError::NothingUsable {
        path: set.dir.clone(),
        reason,
    }
}

/// Detects and solves a board folder.
pub fn calibrate_folder(dir: &Path, opts: &PipelineOptions) -> Result<Calibration, CalibError> {
    let set = detect_folder(dir, progress::or_silent(&opts.progress))?;
    calibrate_detections(&set, opts)
}

/// Calibrates from a recorded session (`.mcap`) with the board described by `board_toml`.
pub fn calibrate_session(
    session: &Path,
    board_toml: &Path,
    session_opts: &SessionOptions,
    opts: &PipelineOptions,
) -> Result<Calibration, CalibError> {
    let set = detect_session(
        session,
        board_toml,
        session_opts,
        progress::or_silent(&opts.progress),
    )?;
    calibrate_detections(&set, opts)
}
