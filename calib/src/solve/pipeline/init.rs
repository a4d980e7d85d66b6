//! Per-camera initialisation through OpenCV: `calibrateCamera` on a spread subset of the
//! views, `solvePnP` for the others, a pinhole guess where OpenCV gives no plausible camera;
//! and the conversions between the crate's camera model and OpenCV's matrices.

use glam::{DQuat, DVec2, DVec3};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;

use crate::error::{CalibError, cv};
use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::model::geometry::Rigid3;

/// A rigid transform from OpenCV's rotation vector and translation.
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
pub(super) fn init_camera(
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
