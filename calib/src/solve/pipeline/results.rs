//! A calibration's figures from the last joint solve: per camera its model, sigmas, RMS (over
//! inliers, over every corner), per-view RMS and tilt, every corner's residual for the plots,
//! and the warnings those figures call for; the warnings of the joint solve itself.

use glam::DVec3;

use super::joint::{Joint, Pairs};
use super::monos::{Found, Monos};
use super::{CameraResult, CornerResidual, ViewRms};
use crate::detect::board::Camera;
use crate::detect::views::DetectedSet;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::solve::lm::PoseFrame;

/// Both cameras' results and the joint RMS over every inlier corner of both.
#[derive(Debug)]
pub(super) struct Results {
    pub(super) cameras: [Option<CameraResult>; 2],
    pub(super) residuals: [Vec<CornerResidual>; 2],
    pub(super) joint_rms_px: f64,
}

/// One camera's residuals in the joint solution.
#[derive(Debug)]
struct CameraFit {
    per_view: Vec<ViewRms>,
    tilts_deg: Vec<f64>,
    residuals: Vec<CornerResidual>,
    /// Sum of squares and count over inlier corners, then over every corner.
    inlier: (f64, usize),
    all: (f64, usize),
}

/// Warnings about the joint solve: too few pairs for the extrinsic, pairs left out, no
/// convergence, unconstrained parameters.
pub(super) fn joint_warnings(both: bool, joint: &Joint, pairs: &Pairs, warnings: &mut Vec<String>) {
    let (pairs_used, report) = (joint.pairs_used, &joint.report);
    if both && pairs_used == 0 {
        warnings.push("no view has the board in both cameras (or no pair is consistent): the thermal↔RGB extrinsic cannot be solved; intrinsics only".into());
    } else if both && pairs_used < 5 {
        warnings.push(format!("only {pairs_used} consistent pairs: the thermal↔RGB extrinsic is weakly constrained (want ≥ 5 pairs at varied poses)"));
    }
    if !pairs.inconsistent.is_empty() {
        warnings.push(format!(
            "{} of {} pairs are not one rigid instant (transfer or residual test, see the report) and were left out of the extrinsic; their images still calibrate their own camera",
            pairs.inconsistent.len(),
            pairs.pair_views.len()
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
}

/// Each camera of the joint solution: its fit, the warnings about it, its result.
pub(super) fn camera_results(
    set: &DetectedSet,
    joint: &Joint,
    found: Found,
    monos: &Monos,
    warnings: &mut Vec<String>,
) -> Results {
    let problem = &joint.problem;
    let res = crate::solve::lm::residuals(problem);
    let mut results = Results {
        cameras: [None, None],
        residuals: [Vec::new(), Vec::new()],
        joint_rms_px: f64::NAN,
    };
    let (mut all_ss, mut all_n) = (0.0, 0usize);
    for camera in Camera::BOTH {
        let k = camera.index();
        let Some(model) = problem.cameras[k] else {
            continue;
        };
        let fit = camera_fit(joint, &res, camera);
        let (ss, n) = fit.inlier;
        let (ss_all, n_all) = fit.all;
        all_ss += ss;
        all_n += n;
        results.residuals[k] = fit.residuals;
        let max_tilt = fit.tilts_deg.iter().copied().fold(0.0, f64::max);
        if max_tilt < 10.0 {
            warnings.push(format!(
                "{}: all {} views are within {max_tilt:.1}° of fronto-parallel: focal length and principal point are poorly constrained (tilt the board 20–45°)",
                camera.name(),
                fit.tilts_deg.len()
            ));
        }
        coverage_warning(camera, &model, &results.residuals[k], warnings);
        let sigma = joint.report.intrinsic_sigma[k].unwrap_or_default();
        let rel = sigma.fx / model.intrinsics.fx;
        if rel.is_nan() || rel >= 0.005 {
            warnings.push(format!(
                "{}: fx uncertainty σ = {:.3} px ({:.2} %) is large",
                camera.name(),
                sigma.fx,
                100.0 * rel
            ));
        }
        let mono = monos.mono[k].as_ref();
        results.cameras[k] = Some(CameraResult {
            camera,
            model,
            sigma,
            images: set.images[k],
            views_found: found.views[k],
            views_partial: found.partial[k],
            views_used: fit.per_view.len(),
            rms_px: (ss / n.max(1) as f64).sqrt(),
            rms_all_px: (ss_all / n_all.max(1) as f64).sqrt(),
            init_rms_px: monos.init_rms[k],
            mono_rms_px: mono.map_or(f64::NAN, |m| m.rms_px),
            mono_rms_all_px: mono.map_or(f64::NAN, |m| m.rms_all_px),
            refinement: monos.refinement[k].clone(),
            per_view: fit.per_view,
        });
    }
    results.joint_rms_px = (all_ss / all_n.max(1) as f64).sqrt();
    results
}

/// `camera`'s observations in the joint solution (`res`: its residuals, per observation).
fn camera_fit(joint: &Joint, res: &[Vec<glam::DVec2>], camera: Camera) -> CameraFit {
    let problem = &joint.problem;
    let mut fit = CameraFit {
        per_view: Vec::new(),
        tilts_deg: Vec::new(),
        residuals: Vec::new(),
        inlier: (0.0, 0),
        all: (0.0, 0),
    };
    for (o, r) in problem.observations.iter().zip(res) {
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
        fit.inlier.0 += vss;
        fit.inlier.1 += vn;
        fit.all.0 += r.iter().map(|e| e.length_squared()).sum::<f64>();
        fit.all.1 += r.len();
        for ((p, e), inl) in o.corners_px.iter().zip(r).zip(&o.inlier) {
            fit.residuals.push(CornerResidual {
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
        fit.tilts_deg.push(tilt);
        fit.per_view.push(ViewRms {
            key: joint.view_keys[o.view].clone(),
            rms_px: (vss / vn.max(1) as f64).sqrt(),
            corners_used: vn,
            tilt_deg: tilt,
        });
    }
    fit
}

/// The board's tilt from fronto-parallel in a camera, degrees.
fn tilt_deg(cam_from_board: &Rigid3) -> f64 {
    let n = cam_from_board.transform_vector(DVec3::Z);
    n.z.abs().clamp(0.0, 1.0).acos().to_degrees()
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
