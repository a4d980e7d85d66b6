//! Board folder → detections → per-camera OpenCV initialisation → one joint LM → result with
//! warnings. Detection and solving are separate steps ([`detect_folder`],
//! [`calibrate_detections`]) so the benchmark can time them apart.
//!
//! RMS figures follow OpenCV: `sqrt(Σ|r|² / N)` over corners (not per axis). The joint RMS
//! is over every inlier corner of both cameras (paired and unpaired views).

use std::path::Path;

use glam::{DQuat, DVec2, DVec3};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use rayon::prelude::*;
use serde::Serialize;

use crate::board::{BoardSpec, Camera, FileProblem};
use crate::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::error::CalibError;
use crate::frontend::{BoardDetection, Refinement};
use crate::geometry::Rigid3;
use crate::pairs::{
    InconsistentPair, MAX_RESIDUAL_ROUNDS, PairEvidence, PairTest, PairThresholds, residual_fails,
    rotation_diff_deg, transfer_test,
};
use crate::session::SessionOptions;
use crate::solve::{
    ExtrinsicSigma, IntrinsicSigma, IterationLog, Observation, PoseFrame, Problem, RejectedCorner,
    SolveOptions, solve,
};
pub use crate::views::{
    DetectedSet, DetectedView, detect_folder, detect_session, detect_views, is_session,
};

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
    /// Pairs left out of the extrinsic, with their figures ([`crate::pairs`]).
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

fn cv(operation: &'static str) -> impl FnOnce(opencv::Error) -> CalibError {
    move |source| CalibError::OpenCv { operation, source }
}

fn rigid_from_rvec_tvec(r: &Mat, t: &Mat) -> Result<Rigid3, CalibError> {
    let rv = DVec3::new(
        *r.at::<f64>(0).map_err(cv("rvec"))?,
        *r.at::<f64>(1).map_err(cv("rvec"))?,
        *r.at::<f64>(2).map_err(cv("rvec"))?,
    );
    let tv = DVec3::new(
        *t.at::<f64>(0).map_err(cv("tvec"))?,
        *t.at::<f64>(1).map_err(cv("tvec"))?,
        *t.at::<f64>(2).map_err(cv("tvec"))?,
    );
    Ok(Rigid3::new(DQuat::from_scaled_axis(rv), tv))
}

/// OpenCV camera matrix and distortion from a model.
pub fn opencv_k_dist(m: &CameraModel) -> Result<(Mat, Mat), CalibError> {
    let i = m.intrinsics;
    let d = m.distortion;
    let k = Mat::from_slice_2d(&[[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]])
        .map_err(cv("camera matrix"))?;
    let dist = Mat::from_slice(&[d.k1, d.k2, d.p1, d.p2, d.k3])
        .map_err(cv("distortion"))?
        .try_clone()
        .map_err(cv("distortion"))?;
    Ok((k, dist))
}

/// Model from OpenCV K and distortion.
pub fn model_from_opencv(k: &Mat, dist: &Mat, size: (u32, u32)) -> Result<CameraModel, CalibError> {
    let g = |r: i32, c: i32| k.at_2d::<f64>(r, c).copied().map_err(cv("K"));
    let d = |i: i32| {
        if i < dist.total() as i32 {
            dist.at::<f64>(i).copied().map_err(cv("dist"))
        } else {
            Ok(0.0)
        }
    };
    Ok(CameraModel {
        width_px: size.0,
        height_px: size.1,
        intrinsics: Intrinsics {
            fx: g(0, 0)?,
            fy: g(1, 1)?,
            cx: g(0, 2)?,
            cy: g(1, 2)?,
        },
        distortion: BrownConrady {
            k1: d(0)?,
            k2: d(1)?,
            p1: d(2)?,
            p2: d(3)?,
            k3: d(4)?,
        },
    })
}

/// One view's corners and the board's index of each (a partial board sees a subset).
pub type ViewCorners<'a> = (&'a [DVec2], &'a [usize]);

/// OpenCV point vectors for detections: per view, the board points of its corners and the
/// corners.
pub fn cv_points(
    object: &[DVec3],
    views: &[ViewCorners],
) -> (Vector<Vector<Point3f>>, Vector<Vector<Point2f>>) {
    let mut o = Vector::new();
    let mut i = Vector::new();
    for (corners, ids) in views {
        o.push(
            ids.iter()
                .filter_map(|&k| object.get(k))
                .map(|p| Point3f::new(p.x as f32, p.y as f32, p.z as f32))
                .collect::<Vector<Point3f>>(),
        );
        i.push(
            corners
                .iter()
                .zip(ids.iter())
                .filter(|(_, k)| **k < object.len())
                .map(|(p, _)| Point2f::new(p.x as f32, p.y as f32))
                .collect::<Vector<Point2f>>(),
        );
    }
    (o, i)
}

fn plausible(m: &CameraModel) -> bool {
    let w = f64::from(m.width_px);
    let h = f64::from(m.height_px);
    let i = m.intrinsics;
    m.validate().is_ok()
        && i.fx > 0.1 * w
        && i.fx < 50.0 * w
        && (i.fy / i.fx - 1.0).abs() < 0.5
        && i.cx > 0.0
        && i.cx < w
        && i.cy > 0.0
        && i.cy < h
}

/// Views `calibrateCamera` initialises a camera on: its dense Levenberg–Marquardt costs
/// ~N³ in the view count (every view adds 6 unknowns to one dense system), so a larger set is
/// initialised on this many views spread over it, and the other views' poses come from
/// `solvePnP` with that camera; the mono and joint solves then refine everything. On the
/// 70-pair synthetic set (Lepton + 720p) everything after detection went from 1.66 s to
/// 0.87 s, every reported figure unchanged.
pub const INIT_VIEWS: usize = 20;

/// Per-camera initialisation (once per camera, on its first refinement's corners): OpenCV
/// `calibrateCamera` (≤ 20 iterations; k3 and tangential fixed at 0 with fewer than 6 views)
/// on at most [`INIT_VIEWS`] views spread over the set, `solvePnP` for the others; falling
/// back to a 53° pinhole guess + `solvePnP` when OpenCV fails or returns an implausible camera
/// (e.g. all views fronto-parallel). The RMS returned is `calibrateCamera`'s on its views.
fn init_camera(
    object: &[DVec3],
    views: &[ViewCorners],
    size: (u32, u32),
    warnings: &mut Vec<String>,
    name: &str,
) -> Result<(CameraModel, Vec<Rigid3>, f64), CalibError> {
    let (obj, img) = cv_points(object, views);
    let subset: Vec<usize> = if views.len() > INIT_VIEWS {
        (0..INIT_VIEWS)
            .map(|i| i * views.len() / INIT_VIEWS)
            .collect()
    } else {
        (0..views.len()).collect()
    };
    let sub_views: Vec<ViewCorners> = subset.iter().map(|&i| views[i]).collect();
    let (sub_obj, sub_img) = cv_points(object, &sub_views);
    let mut k = Mat::default();
    let mut dist = Mat::default();
    let mut rvecs = Vector::<Mat>::new();
    let mut tvecs = Vector::<Mat>::new();
    let flags = if views.len() < 6 {
        calib3d_flags_few()
    } else {
        0
    };
    // The joint LM refines everything afterwards: the init only has to land in its basin.
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        20,
        1e-6,
    )
    .map_err(cv("TermCriteria"))?;
    let res = opencv::calib3d::calibrate_camera(
        &sub_obj,
        &sub_img,
        Size::new(size.0 as i32, size.1 as i32),
        &mut k,
        &mut dist,
        &mut rvecs,
        &mut tvecs,
        flags,
        criteria,
    );
    let (model, rms) = match res {
        Ok(rms)
            if rms.is_finite()
                && let Ok(model) = model_from_opencv(&k, &dist, size)
                && plausible(&model) =>
        {
            (model, rms)
        }
        _ => {
            warnings.push(format!(
                "{name}: OpenCV calibrateCamera gave no plausible initial camera ({}); started from a 53° pinhole guess",
                match res { Ok(r) => format!("RMS {r:.3} px"), Err(e) => e.to_string() }
            ));
            let (w, h) = (f64::from(size.0), f64::from(size.1));
            let model = CameraModel {
                width_px: size.0,
                height_px: size.1,
                intrinsics: Intrinsics {
                    fx: w,
                    fy: w,
                    cx: (w - 1.0) / 2.0,
                    cy: (h - 1.0) / 2.0,
                },
                distortion: BrownConrady::default(),
            };
            rvecs.clear();
            tvecs.clear();
            (model, f64::NAN)
        }
    };
    let (kk, dd) = opencv_k_dist(&model)?;
    let mut poses = Vec::with_capacity(views.len());
    for (i, (o, p)) in obj.iter().zip(img.iter()).enumerate() {
        // A view calibrateCamera solved keeps its pose from there.
        if let Some(j) = subset.iter().position(|&s| s == i)
            && let (Ok(r), Ok(t)) = (rvecs.get(j), tvecs.get(j))
        {
            poses.push(rigid_from_rvec_tvec(&r, &t)?);
            continue;
        }
        let mut r = Mat::default();
        let mut t = Mat::default();
        opencv::calib3d::solve_pnp(
            &o,
            &p,
            &kk,
            &dd,
            &mut r,
            &mut t,
            false,
            opencv::calib3d::SOLVEPNP_ITERATIVE,
        )
        .map_err(cv("solvePnP"))?;
        poses.push(rigid_from_rvec_tvec(&r, &t)?);
    }
    Ok((model, poses, rms))
}

fn calib3d_flags_few() -> i32 {
    opencv::calib3d::CALIB_FIX_K3 | opencv::calib3d::CALIB_ZERO_TANGENT_DIST
}

fn tilt_deg(cam_from_board: &Rigid3) -> f64 {
    let n = cam_from_board.transform_vector(DVec3::Z);
    n.z.abs().clamp(0.0, 1.0).acos().to_degrees()
}

/// Options of a run.
#[derive(Debug, Clone, Copy, Default)]
pub struct PipelineOptions {
    pub solve: SolveOptions,
    /// Thresholds of the pair-consistency tests ([`crate::pairs`]).
    pub pairs: PairThresholds,
    /// Draw an indicatif progress bar over detection.
    pub progress: bool,
}

/// Which sub-pixel refinement a camera's corners use, and the figures that chose it.
#[derive(Debug, Clone, Serialize)]
pub struct RefinementChoice {
    pub kept: Refinement,
    /// Each refinement tried and the camera's mono RMS over every corner with it (px).
    pub mono_rms_all_px: Vec<(Refinement, f64)>,
}

/// One camera calibrated alone on its own views (robust LM with the joint solver's rejection).
#[derive(Debug, Clone)]
struct MonoSolve {
    model: CameraModel,
    /// `(set view index, cam_from_board)`.
    poses: Vec<(usize, Rigid3)>,
    /// `(set view index, inlier RMS px)`.
    view_rms: Vec<(usize, f64)>,
    rms_px: f64,
    rms_all_px: f64,
}

impl MonoSolve {
    fn pose(&self, view: usize) -> Option<Rigid3> {
        self.poses.iter().find(|(v, _)| *v == view).map(|(_, p)| *p)
    }
    fn view_rms(&self, view: usize) -> f64 {
        self.view_rms
            .iter()
            .find(|(v, _)| *v == view)
            .map_or(f64::NAN, |(_, r)| *r)
    }
}

fn solve_mono(
    views: &[ViewCorners],
    object: &[DVec3],
    camera: Camera,
    model: CameraModel,
    init: &[(usize, Rigid3)],
    opts: &SolveOptions,
) -> MonoSolve {
    let k = camera.index();
    let frame = match camera {
        Camera::Thermal => PoseFrame::Thermal,
        Camera::Rgb => PoseFrame::Rgb,
    };
    let mut cameras = [None, None];
    cameras[k] = Some(model);
    let mut problem = Problem {
        object_points_m: object.to_vec(),
        cameras,
        rgb_from_thermal: None,
        poses: init.iter().map(|(_, p)| (frame, *p)).collect(),
        observations: views
            .iter()
            .enumerate()
            .map(|(i, (corners, ids))| {
                Observation::subset(camera, i, corners.to_vec(), ids.to_vec())
            })
            .collect(),
    };
    solve(&mut problem, opts);
    let res = crate::solve::residuals(&problem);
    let (mut ss, mut n, mut ss_all, mut n_all) = (0.0, 0usize, 0.0, 0usize);
    let mut view_rms = Vec::new();
    for (o, r) in problem.observations.iter().zip(&res) {
        let (mut vs, mut vn) = (0.0, 0usize);
        for (e, inl) in r.iter().zip(&o.inlier) {
            ss_all += e.length_squared();
            n_all += 1;
            if *inl {
                vs += e.length_squared();
                vn += 1;
            }
        }
        ss += vs;
        n += vn;
        view_rms.push((init[o.view].0, (vs / vn.max(1) as f64).sqrt()));
    }
    MonoSolve {
        model: problem.cameras[k].unwrap_or(model),
        poses: init
            .iter()
            .zip(&problem.poses)
            .map(|((v, _), (_, p))| (*v, *p))
            .collect(),
        view_rms,
        rms_px: (ss / n.max(1) as f64).sqrt(),
        rms_all_px: (ss_all / n_all.max(1) as f64).sqrt(),
    }
}

/// The joint problem from the mono solutions: a view in both cameras and not `split` is a
/// pair (one board pose, RGB through the extrinsic); any other view is one or two
/// single-camera views. Returns the problem, the solver views' keys, the set view each came
/// from, and the number of pairs.
fn joint_problem(
    set: &DetectedSet,
    object: &[DVec3],
    mono: &[Option<MonoSolve>; 2],
    split: &[bool],
    rgb_from_thermal: Option<Rigid3>,
) -> (Problem, Vec<String>, Vec<usize>, usize) {
    let mut poses = Vec::new();
    let mut observations = Vec::new();
    let mut keys = Vec::new();
    let mut source = Vec::new();
    let mut pairs = 0usize;
    let pose = |k: usize, v: usize| mono[k].as_ref().and_then(|m| m.pose(v));
    let mut observe = |camera: Camera, view: usize, d: &BoardDetection| {
        observations.push(Observation::subset(
            camera,
            view,
            d.corners_px.clone(),
            d.corner_ids.clone(),
        ));
    };
    for (v, view) in set.views.iter().enumerate() {
        let dets = &view.detections;
        match (pose(0, v), pose(1, v)) {
            (Some(t), Some(_)) if !split[v] && rgb_from_thermal.is_some() => {
                let index = poses.len();
                poses.push((PoseFrame::Thermal, t));
                keys.push(view.key.clone());
                source.push(v);
                for camera in Camera::BOTH {
                    if let Some(d) = &dets[camera.index()] {
                        observe(camera, index, d);
                    }
                }
                pairs += 1;
            }
            (t, r) => {
                for (camera, frame, p) in [
                    (Camera::Thermal, PoseFrame::Thermal, t),
                    (Camera::Rgb, PoseFrame::Rgb, r),
                ] {
                    if let (Some(p), Some(d)) = (p, &dets[camera.index()]) {
                        let index = poses.len();
                        poses.push((frame, p));
                        keys.push(view.key.clone());
                        source.push(v);
                        observe(camera, index, d);
                    }
                }
            }
        }
    }
    let problem = Problem {
        object_points_m: object.to_vec(),
        cameras: [
            mono[0].as_ref().map(|m| m.model),
            mono[1].as_ref().map(|m| m.model),
        ],
        rgb_from_thermal: if pairs > 0 { rgb_from_thermal } else { None },
        poses,
        observations,
    };
    (problem, keys, source, pairs)
}

/// Inlier RMS per solver view and camera (`[thermal, rgb]`, NaN where the camera is absent).
fn view_rms(p: &Problem) -> Vec<[f64; 2]> {
    let mut out = vec![[f64::NAN; 2]; p.poses.len()];
    for (o, r) in p.observations.iter().zip(crate::solve::residuals(p)) {
        let (ss, n) = r
            .iter()
            .zip(&o.inlier)
            .filter(|(_, i)| **i)
            .fold((0.0, 0usize), |(s, n), (e, _)| {
                (s + e.length_squared(), n + 1)
            });
        out[o.view][o.camera.index()] = (ss / n.max(1) as f64).sqrt();
    }
    out
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
        // RMS over every corner) is kept for the joint solve. See `frontend::Refinement`.
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
    let res = crate::solve::residuals(&problem);
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
    let set = detect_folder(dir, opts.progress)?;
    calibrate_detections(&set, opts)
}

/// Calibrates from a recorded session (`.mcap`) with the board described by `board_toml`.
pub fn calibrate_session(
    session: &Path,
    board_toml: &Path,
    session_opts: &SessionOptions,
    opts: &PipelineOptions,
) -> Result<Calibration, CalibError> {
    let set = detect_session(session, board_toml, session_opts, opts.progress)?;
    calibrate_detections(&set, opts)
}
