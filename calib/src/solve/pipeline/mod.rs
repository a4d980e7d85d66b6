//! Board folder → detections → per-camera OpenCV initialisation → one joint LM → result with
//! warnings. Detection and solving are separate steps ([`detect_folder`],
//! [`calibrate_detections`]) so the benchmark can time them apart.
//!
//! RMS figures follow OpenCV: `sqrt(Σ|r|² / N)` over corners (not per axis). The joint RMS
//! is over every inlier corner of both cameras (paired and unpaired views).
//!
//! This module runs the steps and builds the [`Calibration`] with its warnings; `init` holds
//! the per-camera OpenCV initialisation (and the model ↔ OpenCV conversions), `solves` the
//! mono solves and the joint problem assembled from them; the pair tests are [`crate::solve::pairs`],
//! detection over a folder or session [`crate::detect::views`].

mod init;
mod solves;

use std::path::Path;
use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;
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
    ExtrinsicSigma, IntrinsicSigma, IterationLog, PoseFrame, RejectedCorner, SolveOptions, solve,
};
use crate::solve::pairs::{
    InconsistentPair, MAX_RESIDUAL_ROUNDS, PairEvidence, PairTest, PairThresholds, residual_fails,
    rotation_diff_deg, transfer_test,
};
use init::init_camera;
pub use init::{INIT_VIEWS, ViewCorners, cv_points, model_from_opencv, opencv_k_dist};
use solves::{MonoSolve, joint_problem, solve_mono, view_rms};

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

fn tilt_deg(cam_from_board: &Rigid3) -> f64 {
    let n = cam_from_board.transform_vector(DVec3::Z);
    n.z.abs().clamp(0.0, 1.0).acos().to_degrees()
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
    let set = &mut set;
    let mut warnings = set.notes.clone();
    let mut warnings_init: [Vec<String>; 2] = [Vec::new(), Vec::new()];
    let mut refinement: [Option<RefinementChoice>; 2] = [None, None];
    let mut mono: [Option<MonoSolve>; 2] = [None, None];
    let object = set.board.object_points_m();
    let mut cameras: [Option<CameraModel>; 2] = [None, None];
    let mut init_poses: [Vec<(usize, Rigid3)>; 2] = [Vec::new(), Vec::new()];
    let mut init_rms = [f64::NAN; 2];
    let mut views_found = [0usize; 2];
    let mut views_partial = [0usize; 2];
    // Per camera with enough views: (camera, its set views, image size, refinements to try).
    type Plan = (Camera, Vec<usize>, (u32, u32), Vec<Refinement>);
    let mut plans: Vec<Plan> = Vec::new();
    for camera in Camera::BOTH {
        let k = camera.index();
        let idx: Vec<usize> = set
            .views
            .iter()
            .enumerate()
            .filter(|(_, v)| v.detections[k].is_some())
            .map(|(i, _)| i)
            .collect();
        views_found[k] = idx.len();
        views_partial[k] = idx
            .iter()
            .filter(|&&i| {
                set.views[i].detections[k]
                    .as_ref()
                    .is_some_and(|d| d.corner_ids.len() < object.len())
            })
            .count();
        if set.images[k] == 0 {
            continue;
        }
        let Some(size) = set.image_size[k] else {
            warnings.push(format!("{}: no readable image", camera.name()));
            continue;
        };
        if idx.len() < 3 {
            warnings.push(format!(
                "{}: the board was found in only {} of {} images; at least 3 are needed, camera left out",
                camera.name(),
                idx.len(),
                set.images[k]
            ));
            continue;
        }
        if idx.len() < 6 {
            warnings.push(format!(
                "{}: the board was found in only {} views: intrinsics (distortion especially) are weakly constrained",
                camera.name(),
                idx.len()
            ));
        }
        // Sub-pixel refinement per camera: every refinement the detections carry is tried,
        // and the one whose corners this camera's own calibration explains best (lowest mono
        // RMS over every corner) is kept for the joint solve. See [`Refinement`].
        let mut options: Vec<Refinement> = Vec::new();
        for &i in &idx {
            for (r, _) in set.views[i].detections[k].iter().flat_map(|d| &d.variants) {
                if !options.contains(r) {
                    options.push(*r);
                }
            }
        }
        if options.is_empty() {
            options.push(Refinement::CornerSubPix);
        }
        plans.push((camera, idx, size, options));
    }
    // OpenCV's calibrateCamera initialises each camera once, on its first refinement's corners
    // (the refinements differ by sub-pixel amounts, so one init lands every mono solve in its
    // basin; on sun-board everything after detection took 1.33 s with an init per refinement,
    // 0.83 s with one). The two cameras' inits, then all their mono solves, run in parallel
    // (one batch, so the two cores stay busy) and are taken in order.
    let views_of = |camera: Camera, idx: &[usize], r: Refinement| -> Vec<ViewCorners> {
        idx.iter()
            .filter_map(|&i| {
                set.views[i].detections[camera.index()]
                    .as_ref()
                    .map(|d| (d.corners_of(r), d.corner_ids.as_slice()))
            })
            .collect()
    };
    type Init = (CameraModel, Vec<Rigid3>, f64, Vec<String>);
    let inits: Vec<Init> = plans
        .par_iter()
        .map(|(camera, idx, size, options)| {
            let mut init_warnings = Vec::new();
            let (model, poses, rms) = init_camera(
                &object,
                &views_of(*camera, idx, options[0]),
                *size,
                &mut init_warnings,
                camera.name(),
            )?;
            Ok((model, poses, rms, init_warnings))
        })
        .collect::<Result<_, CalibError>>()?;
    let jobs: Vec<(usize, Refinement)> = plans
        .iter()
        .enumerate()
        .flat_map(|(p, (_, _, _, options))| options.iter().map(move |r| (p, *r)))
        .collect();
    let solved: Vec<MonoSolve> = jobs
        .par_iter()
        .map(|&(p, r)| {
            let (camera, idx, _, _) = &plans[p];
            let (model, poses, _, _) = &inits[p];
            let init: Vec<(usize, Rigid3)> = idx.iter().copied().zip(poses.clone()).collect();
            solve_mono(
                &views_of(*camera, idx, r),
                &object,
                *camera,
                *model,
                &init,
                &opts.solve,
            )
        })
        .collect();
    let mut solved = jobs.into_iter().zip(solved);
    for ((camera, idx, _, options), (model, poses, rms, init_warnings)) in
        plans.into_iter().zip(inits)
    {
        let k = camera.index();
        warnings_init[k] = init_warnings;
        let mut tried: Vec<(Refinement, f64)> = Vec::new();
        let mut best: Option<(Refinement, MonoSolve)> = None;
        for ((_, r), m) in solved.by_ref().take(options.len()) {
            tried.push((r, m.rms_all_px));
            if best
                .as_ref()
                .is_none_or(|b| m.rms_all_px < b.1.rms_all_px || !b.1.rms_all_px.is_finite())
            {
                best = Some((r, m));
            }
        }
        if let Some((r, m)) = best {
            for &i in &idx {
                if let Some(d) = set.views[i].detections[k].as_mut() {
                    d.choose(r);
                }
            }
            refinement[k] = Some(RefinementChoice {
                kept: r,
                mono_rms_all_px: tried,
            });
            cameras[k] = Some(model);
            init_rms[k] = rms;
            init_poses[k] = idx.into_iter().zip(poses).collect();
            mono[k] = Some(m);
        }
    }
    warnings.extend(warnings_init.into_iter().flatten());
    if cameras.iter().all(Option::is_none) {
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
        return Err(CalibError::NothingUsable {
            path: set.dir.clone(),
            reason,
        });
    }
    let both = mono.iter().all(Option::is_some);
    // Pairs: views with the board in both cameras. Test 1 (pose difference) on mono poses.
    let is_pair: Vec<bool> = (0..set.views.len())
        .map(|v| match &mono {
            [Some(t), Some(r)] => t.pose(v).is_some() && r.pose(v).is_some(),
            _ => false,
        })
        .collect();
    let pair_views: Vec<usize> = (0..set.views.len()).filter(|&v| is_pair[v]).collect();
    let mut split = vec![false; set.views.len()];
    let mut inconsistent = Vec::new();
    let mut rgb_from_thermal = None;
    if let [Some(mt), Some(mr)] = &mono {
        let mut used = Vec::new();
        let evidence: Vec<PairEvidence> = pair_views
            .iter()
            .filter_map(|&v| {
                let d = set.views[v].detections[0].as_ref()?;
                used.push(v);
                Some(PairEvidence {
                    thermal_from_board: mt.pose(v)?,
                    rgb_from_board: mr.pose(v)?,
                    thermal_corners_px: &d.corners_px,
                    thermal_corner_ids: &d.corner_ids,
                    thermal_mono_rms_px: mt.view_rms(v),
                })
            })
            .collect();
        let test = transfer_test(&evidence, &mt.model, &object, &opts.pairs);
        for (i, &v) in used.iter().enumerate() {
            if test.agrees[i] {
                continue;
            }
            split[v] = true;
            let own = evidence[i].extrinsic();
            inconsistent.push(InconsistentPair {
                key: set.views[v].key.clone(),
                test: PairTest::Transfer,
                rotation_diff_deg: rotation_diff_deg(own.rotation, test.consensus.rotation),
                translation_diff_m: (own.translation_m - test.consensus.translation_m).length(),
                transfer_rms_px: test.transfer_rms_px[i],
                joint_rms_px: [f64::NAN; 2],
                mono_rms_px: [mt.view_rms(v), mr.view_rms(v)],
            });
        }
        if !evidence.is_empty() {
            rgb_from_thermal = Some(test.consensus);
        }
    }
    // Joint solve; test 2 (residual) on its result, splitting failing pairs and solving again.
    let mut round = 0;
    let (problem, view_keys, report, pairs_used) = loop {
        let (mut problem, view_keys, source, pairs_used) =
            joint_problem(set, &object, &mono, &split, rgb_from_thermal);
        let report = solve(&mut problem, &opts.solve);
        round += 1;
        let mut newly = Vec::new();
        if let [Some(mt), Some(mr)] = &mono
            && round <= MAX_RESIDUAL_ROUNDS
            && problem.rgb_from_thermal.is_some()
        {
            let per_view = view_rms(&problem);
            for (pv, &v) in source.iter().enumerate() {
                if split[v] || !is_pair[v] {
                    continue;
                }
                let joint = [per_view[pv][0], per_view[pv][1]];
                let mono_rms = [mt.view_rms(v), mr.view_rms(v)];
                if residual_fails(joint, mono_rms, &opts.pairs) {
                    let ext = problem.rgb_from_thermal.unwrap_or(Rigid3::IDENTITY);
                    let own = match (mt.pose(v), mr.pose(v)) {
                        (Some(t), Some(r)) => r.compose(&t.inverse()),
                        _ => ext,
                    };
                    newly.push(v);
                    inconsistent.push(InconsistentPair {
                        key: set.views[v].key.clone(),
                        test: PairTest::Residual,
                        rotation_diff_deg: rotation_diff_deg(own.rotation, ext.rotation),
                        translation_diff_m: (own.translation_m - ext.translation_m).length(),
                        transfer_rms_px: f64::NAN,
                        joint_rms_px: joint,
                        mono_rms_px: mono_rms,
                    });
                }
            }
        }
        if newly.is_empty() {
            break (problem, view_keys, report, pairs_used);
        }
        for v in newly {
            split[v] = true;
        }
        // The next round starts from this round's extrinsic.
        rgb_from_thermal = problem.rgb_from_thermal;
    };
    if both && pairs_used == 0 {
        warnings.push("no view has the board in both cameras (or no pair is consistent): the thermal↔RGB extrinsic cannot be solved; intrinsics only".into());
    } else if both && pairs_used < 5 {
        warnings.push(format!("only {pairs_used} consistent pairs: the thermal↔RGB extrinsic is weakly constrained (want ≥ 5 pairs at varied poses)"));
    }
    if !inconsistent.is_empty() {
        warnings.push(format!(
            "{} of {} pairs are not one rigid instant (transfer or residual test, see the report) and were left out of the extrinsic; their images still calibrate their own camera",
            inconsistent.len(),
            pair_views.len()
        ));
    }
    if !report.converged {
        warnings.push(format!(
            "the solver stopped after {} iterations without converging",
            report.iterations.len()
        ));
    }
    if !report.unconstrained.is_empty() {
        warnings.push(format!(
            "parameters the data do not constrain (information ≈ 0): {}",
            report.unconstrained.join(", ")
        ));
    }
    // Per-camera results.
    let res = crate::solve::lm::residuals(&problem);
    let mut out_cameras: [Option<CameraResult>; 2] = [None, None];
    let mut corner_res: [Vec<CornerResidual>; 2] = [Vec::new(), Vec::new()];
    let (mut all_ss, mut all_n) = (0.0, 0usize);
    for camera in Camera::BOTH {
        let k = camera.index();
        let Some(model) = problem.cameras[k] else {
            continue;
        };
        let (mut ss, mut n) = (0.0, 0usize);
        let (mut ss_all, mut n_all) = (0.0, 0usize);
        let mut per_view = Vec::new();
        let mut tilts = Vec::new();
        for (o, r) in problem.observations.iter().zip(&res) {
            if o.camera != camera {
                continue;
            }
            let (vss, vn) = o
                .inlier
                .iter()
                .zip(r)
                .filter(|(i, _)| **i)
                .fold((0.0, 0usize), |(s, n), (_, e)| {
                    (s + e.length_squared(), n + 1)
                });
            ss += vss;
            n += vn;
            ss_all += r.iter().map(|e| e.length_squared()).sum::<f64>();
            n_all += r.len();
            for ((p, e), inl) in o.corners_px.iter().zip(r).zip(&o.inlier) {
                corner_res[k].push(CornerResidual {
                    observed_px: *p,
                    residual_px: *e,
                    inlier: *inl,
                });
            }
            let (frame, pose) = problem.poses[o.view];
            let cam_from_board = match (camera, frame, problem.rgb_from_thermal) {
                (Camera::Rgb, PoseFrame::Thermal, Some(e)) => e.compose(&pose),
                _ => pose,
            };
            let tilt = tilt_deg(&cam_from_board);
            tilts.push(tilt);
            per_view.push(ViewRms {
                key: view_keys[o.view].clone(),
                rms_px: (vss / vn.max(1) as f64).sqrt(),
                corners_used: vn,
                tilt_deg: tilt,
            });
        }
        all_ss += ss;
        all_n += n;
        let max_tilt = tilts.iter().copied().fold(0.0, f64::max);
        if max_tilt < 10.0 {
            warnings.push(format!(
                "{}: all {} views are within {max_tilt:.1}° of fronto-parallel: focal length and principal point are poorly constrained (tilt the board 20–45°)",
                camera.name(),
                tilts.len()
            ));
        }
        coverage_warning(camera, &model, &corner_res[k], &mut warnings);
        let sigma = report.intrinsic_sigma[k].unwrap_or_default();
        let rel = sigma.fx / model.intrinsics.fx;
        if rel.is_nan() || rel >= 0.005 {
            warnings.push(format!(
                "{}: fx uncertainty σ = {:.3} px ({:.2} %) is large",
                camera.name(),
                sigma.fx,
                100.0 * rel
            ));
        }
        out_cameras[k] = Some(CameraResult {
            camera,
            model,
            sigma,
            images: set.images[k],
            views_found: views_found[k],
            views_partial: views_partial[k],
            views_used: per_view.len(),
            rms_px: (ss / n.max(1) as f64).sqrt(),
            rms_all_px: (ss_all / n_all.max(1) as f64).sqrt(),
            init_rms_px: init_rms[k],
            mono_rms_px: mono[k].as_ref().map_or(f64::NAN, |m| m.rms_px),
            mono_rms_all_px: mono[k].as_ref().map_or(f64::NAN, |m| m.rms_all_px),
            refinement: refinement[k].clone(),
            per_view,
        });
    }
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
        cameras: out_cameras,
        rgb_from_thermal: problem.rgb_from_thermal,
        extrinsic_sigma: report.extrinsic_sigma,
        joint_rms_px: (all_ss / all_n.max(1) as f64).sqrt(),
        pairs_used,
        pairs_found: pair_views.len(),
        pairs_inconsistent: inconsistent,
        pair_thresholds: opts.pairs,
        warnings,
        problems: set.problems.clone(),
        rejected: report.rejected,
        iterations: report.iterations,
        polarity_note: set.polarity_note.clone(),
        detection_wall_s: set.detection_wall_s,
        solve_wall_s: report.wall_s,
        converged: report.converged,
        residuals: corner_res,
        view_keys,
    })
}

/// Warns when none of the detected corners reach an image corner (outer third in x and y).
fn coverage_warning(
    camera: Camera,
    model: &CameraModel,
    corners: &[CornerResidual],
    warnings: &mut Vec<String>,
) {
    let (w, h) = (f64::from(model.width_px), f64::from(model.height_px));
    let mut hit = [false; 4];
    for c in corners {
        let p = c.observed_px;
        let left = p.x < w / 3.0;
        let right = p.x > 2.0 * w / 3.0;
        let top = p.y < h / 3.0;
        let bottom = p.y > 2.0 * h / 3.0;
        hit[0] |= left && top;
        hit[1] |= right && top;
        hit[2] |= left && bottom;
        hit[3] |= right && bottom;
    }
    let names = ["top-left", "top-right", "bottom-left", "bottom-right"];
    let missing: Vec<&str> = names
        .iter()
        .zip(hit)
        .filter(|(_, h)| !h)
        .map(|(n, _)| *n)
        .collect();
    if !missing.is_empty() {
        warnings.push(format!(
            "{}: no corner was detected in the {} image corner(s): distortion is extrapolated there",
            camera.name(),
            missing.join(", ")
        ));
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
