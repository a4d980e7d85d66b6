//! The solver problems calibration builds from detections: one camera alone on its own views
//! (the mono solves, also the pair tests' reference), and the joint problem assembled from the
//! mono solutions (pairs through the extrinsic, every other view on its own), with the
//! per-view RMS the residual pair test reads.

use glam::DVec3;

use super::init::ViewCorners;
use crate::detect::board::Camera;
use crate::detect::frontend::BoardDetection;
use crate::detect::views::DetectedSet;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::solve::lm::{Observation, PoseFrame, Problem, SolveOptions, solve};

/// One camera calibrated alone on its own views (robust LM with the joint solver's rejection).
#[derive(Debug, Clone)]
pub(super) struct MonoSolve {
    pub(super) model: CameraModel,
    /// `(set view index, cam_from_board)`.
    pub(super) poses: Vec<(usize, Rigid3)>,
    /// `(set view index, inlier RMS px)`.
    pub(super) view_rms: Vec<(usize, f64)>,
    pub(super) rms_px: f64,
    pub(super) rms_all_px: f64,
}

impl MonoSolve {
    pub(super) fn pose(&self, view: usize) -> Option<Rigid3> {
        self.poses.iter().find(|(v, _)| *v == view).map(|(_, p)| *p)
    }
    pub(super) fn view_rms(&self, view: usize) -> f64 {
        self.view_rms
            .iter()
            .find(|(v, _)| *v == view)
            .map_or(f64::NAN, |(_, r)| *r)
    }
}

/// Calibrates `camera` alone on its views from `model` and the initial poses `init`
/// (`(set view index, cam_from_board)`, one per view).
pub(super) fn solve_mono(
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
    let res = crate::solve::lm::residuals(&problem);
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
pub(super) fn joint_problem(
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
pub(super) fn view_rms(p: &Problem) -> Vec<[f64; 2]> {
    let mut out = vec![[f64::NAN; 2]; p.poses.len()];
    for (o, r) in p.observations.iter().zip(crate::solve::lm::residuals(p)) {
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
