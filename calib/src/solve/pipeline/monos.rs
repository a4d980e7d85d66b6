//! The cameras' own solves, before the joint one: which cameras have enough views (and which
//! sub-pixel refinements their detections carry), OpenCV's initialisation of each, a mono
//! solve per camera and refinement, and the refinement each camera keeps.

use glam::DVec3;
use rayon::prelude::*;

use super::RefinementChoice;
use super::init::{ViewCorners, init_camera};
use super::solves::{MonoSolve, solve_mono};
use crate::detect::board::Camera;
use crate::detect::frontend::Refinement;
use crate::detect::views::DetectedSet;
use crate::error::CalibError;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::solve::lm::SolveOptions;

/// Per camera: views with the board found, and of those the ones found as a partial board.
#[derive(Debug, Clone, Copy)]
pub(super) struct Found {
    pub(super) views: [usize; 2],
    pub(super) partial: [usize; 2],
}

/// A camera with enough views to calibrate.
#[derive(Debug)]
pub(super) struct Plan {
    camera: Camera,
    /// Its views (indices into the set).
    idx: Vec<usize>,
    size: (u32, u32),
    /// The refinements to try, the first one initialises.
    options: Vec<Refinement>,
}

/// What the mono stage hands on, per camera (`None`/NaN: the camera is left out).
#[derive(Debug)]
pub(super) struct Monos {
    pub(super) mono: [Option<MonoSolve>; 2],
    /// OpenCV `calibrateCamera` RMS of the initialisation (px).
    pub(super) init_rms: [f64; 2],
    pub(super) refinement: [Option<RefinementChoice>; 2],
    /// The initialisation's warnings, thermal's first.
    pub(super) init_warnings: [Vec<String>; 2],
}

/// OpenCV's initialisation of one camera: model, a pose per view, RMS, warnings.
type Init = (CameraModel, Vec<Rigid3>, f64, Vec<String>);

/// Counts each camera's views (`corners`: the board's) and plans the cameras with enough of them (at least 3; fewer
/// than 6 is warned about), with the refinements their detections carry.
pub(super) fn plan_cameras(
    set: &DetectedSet,
    corners: usize,
    warnings: &mut Vec<String>,
) -> (Vec<Plan>, Found) {
    let mut found = Found {
        views: [0; 2],
        partial: [0; 2],
    };
    let mut plans = Vec::new();
    for camera in Camera::BOTH {
        let k = camera.index();
        let idx: Vec<usize> = set
            .views
            .iter()
            .enumerate()
            .filter(|(_, v)| v.detections[k].is_some())
            .map(|(i, _)| i)
            .collect();
        found.views[k] = idx.len();
        found.partial[k] = idx
            .iter()
            .filter(|&&i| {
                set.views[i].detections[k]
                    .as_ref()
                    .is_some_and(|d| d.corner_ids.len() < corners)
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
        let options = refinements_to_try(set, k, &idx);
        plans.push(Plan {
            camera,
            idx,
            size,
            options,
        });
    }
    (plans, found)
}

/// Sub-pixel refinement per camera: every refinement the detections carry is tried, and the
/// one whose corners this camera's own calibration explains best (lowest mono RMS over every
/// corner) is kept for the joint solve. See [`Refinement`].
fn refinements_to_try(set: &DetectedSet, k: usize, idx: &[usize]) -> Vec<Refinement> {
    let mut options: Vec<Refinement> = Vec::new();
    for &i in idx {
        for (r, _) in set.views[i].detections[k].iter().flat_map(|d| &d.variants) {
            if !options.contains(r) {
                options.push(*r);
            }
        }
    }
    if options.is_empty() {
        options.push(Refinement::CornerSubPix);
    }
    options
}

/// A camera's corners in its views `idx` with refinement `r`.
fn views_of<'a>(
    set: &'a DetectedSet,
    camera: Camera,
    idx: &[usize],
    r: Refinement,
) -> Vec<ViewCorners<'a>> {
    idx.iter()
        .filter_map(|&i| {
            set.views[i].detections[camera.index()]
                .as_ref()
                .map(|d| (d.corners_of(r), d.corner_ids.as_slice()))
        })
        .collect()
}

/// Initialises and solves every planned camera alone, then keeps each camera's best
/// refinement (chosen in `set`'s detections, which the joint solve reads).
pub(super) fn solve_monos(
    set: &mut DetectedSet,
    object: &[DVec3],
    plans: Vec<Plan>,
    opts: &SolveOptions,
) -> Result<Monos, CalibError> {
    let (inits, solved) = init_and_solve(set, object, &plans, opts)?;
    Ok(keep_best(set, plans, inits, solved))
}

/// OpenCV's calibrateCamera initialises each camera once, on its first refinement's corners
/// (the refinements differ by sub-pixel amounts, so one init lands every mono solve in its
/// basin; on sun-board everything after detection took 1.33 s with an init per refinement,
/// 0.83 s with one). The two cameras' inits, then all their mono solves, run in parallel
/// (one batch, so the two cores stay busy) and are taken in order: the solves come back as
/// `((plan, refinement), solve)`, plan by plan.
#[allow(clippy::type_complexity)]
fn init_and_solve(
    set: &DetectedSet,
    object: &[DVec3],
    plans: &[Plan],
    opts: &SolveOptions,
) -> Result<(Vec<Init>, Vec<((usize, Refinement), MonoSolve)>), CalibError> {
    let inits: Vec<Init> = plans
        .par_iter()
        .map(|p| {
            let mut init_warnings = Vec::new();
            let (model, poses, rms) = init_camera(
                object,
                &views_of(set, p.camera, &p.idx, p.options[0]),
                p.size,
                &mut init_warnings,
                p.camera.name(),
            )?;
            Ok((model, poses, rms, init_warnings))
        })
        .collect::<Result<_, CalibError>>()?;
    let jobs: Vec<(usize, Refinement)> = plans
        .iter()
        .enumerate()
        .flat_map(|(p, plan)| plan.options.iter().map(move |r| (p, *r)))
        .collect();
    let solved: Vec<MonoSolve> = jobs
        .par_iter()
        .map(|&(p, r)| {
            let Plan { camera, idx, .. } = &plans[p];
            let (model, poses, _, _) = &inits[p];
            let init: Vec<(usize, Rigid3)> = idx.iter().copied().zip(poses.clone()).collect();
            solve_mono(
                &views_of(set, *camera, idx, r),
                object,
                *camera,
                *model,
                &init,
                opts,
            )
        })
        .collect();
    Ok((inits, jobs.into_iter().zip(solved).collect()))
}

/// Per camera, the refinement with the lowest mono RMS over every corner (a non-finite RMS
/// loses to any other): chosen in the detections, its solve and figures kept.
fn keep_best(
    set: &mut DetectedSet,
    plans: Vec<Plan>,
    inits: Vec<Init>,
    solved: Vec<((usize, Refinement), MonoSolve)>,
) -> Monos {
    let mut monos = Monos {
        mono: [None, None],
        init_rms: [f64::NAN; 2],
        refinement: [None, None],
        init_warnings: [Vec::new(), Vec::new()],
    };
    let mut solved = solved.into_iter();
    for (plan, (_, _, rms, init_warnings)) in plans.into_iter().zip(inits) {
        let k = plan.camera.index();
        monos.init_warnings[k] = init_warnings;
        let mut tried: Vec<(Refinement, f64)> = Vec::new();
        let mut best: Option<(Refinement, MonoSolve)> = None;
        for ((_, r), m) in solved.by_ref().take(plan.options.len()) {
            tried.push((r, m.rms_all_px));
            if best
                .as_ref()
                .is_none_or(|b| m.rms_all_px < b.1.rms_all_px || !b.1.rms_all_px.is_finite())
            {
                best = Some((r, m));
            }
        }
        if let Some((r, m)) = best {
            for &i in &plan.idx {
                if let Some(d) = set.views[i].detections[k].as_mut() {
                    d.choose(r);
                }
            }
            monos.refinement[k] = Some(RefinementChoice {
                kept: r,
                mono_rms_all_px: tried,
            });
            monos.init_rms[k] = rms;
            monos.mono[k] = Some(m);
        }
    }
    monos
}
