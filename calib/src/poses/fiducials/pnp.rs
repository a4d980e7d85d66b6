//! The fast path's poses: a keyframe posed by perspective-n-point on the corners of the mapped
//! tags it sees (a planar homography of one tag as the start, Gauss–Newton on every corner,
//! the calibrated distortion removed first), and the poses that jump from their neighbours in
//! time dropped.

use std::collections::BTreeMap;

use glam::{DMat3, DQuat, DVec2, DVec3};
use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, Vector6};

use super::TagMap;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::tags::TagDetection;

/// A keyframe is posed by PnP only with at least this many mapped tags in view (module docs).
pub const MIN_PNP_TAGS: usize = 2;
/// A PnP pose is kept when its corners reproject within this RMS, pixels.
pub const MAX_PNP_RMS_PX: f64 = 2.0;

/// A keyframe posed from the tags in view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagPose {
    pub world_from_cam: Rigid3,
    /// Corner reprojection RMS, pixels.
    pub rms_px: f64,
    /// Mapped tags used.
    pub tags: usize,
}

/// A world point and its undistorted normalised image point.
type Correspondence = (DVec3, DVec2);

/// Undistorted normalised coordinates of a detected corner.
pub(super) fn normalised(camera: &CameraModel, px: [f64; 2]) -> Option<DVec2> {
    camera
        .unproject(DVec2::new(px[0], px[1]))
        .map(|r| DVec2::new(r.x, r.y))
}

/// Pose of a keyframe from the mapped tags it sees (module docs); `None` with fewer than
/// [`MIN_PNP_TAGS`] mapped tags or a reprojection RMS above [`MAX_PNP_RMS_PX`].
pub fn pnp(map: &TagMap, camera: &CameraModel, seen: &[TagDetection]) -> Option<TagPose> {
    let mut tags: Vec<(u32, [Correspondence; 4])> = Vec::new();
    for d in seen {
        let Some(world) = map.corners.get(&d.id) else {
            continue;
        };
        let mut pairs = [(DVec3::ZERO, DVec2::ZERO); 4];
        let mut ok = true;
        for (k, pair) in pairs.iter_mut().enumerate() {
            match normalised(camera, d.corners_px[k]) {
                Some(x) => *pair = (world[k], x),
                None => ok = false,
            }
        }
        if ok && !tags.iter().any(|t| t.0 == d.id) {
            tags.push((d.id, pairs));
        }
    }
    if tags.len() < MIN_PNP_TAGS {
        return None;
    }
    let all: Vec<Correspondence> = tags.iter().flat_map(|t| t.1).collect();
    let focal = 0.5 * (camera.intrinsics.fx + camera.intrinsics.fy);
    // Start from each tag's own planar pose; keep the refinement that fits every corner best.
    let best = tags
        .iter()
        .filter_map(|(_, corners)| planar_pose(corners))
        .map(|start| refine(start, &all))
        .map(|pose| (rms(&pose, &all) * focal, pose))
        .filter(|(r, _)| r.is_finite())
        .min_by(|a, b| a.0.total_cmp(&b.0))?;
    (best.0 <= MAX_PNP_RMS_PX).then(|| TagPose {
        world_from_cam: best.1.inverse(),
        rms_px: best.0,
        tags: tags.len(),
    })
}

/// A PnP pose is dropped when it is this far (degrees or metres) from the interpolation of its
/// posed neighbours in time (each within [`NEIGHBOUR_S`]).
pub const OUTLIER_DEG: f64 = 1.0;
pub const OUTLIER_M: f64 = 0.05;
pub const NEIGHBOUR_S: f64 = 0.7;

/// Drops PnP poses that disagree with their neighbours in time (a hand does not jump a degree
/// in a fraction of a second; a tag decoded at a wrong corner does), worst first
/// ([`crate::poses::interp::drop_worst_jumps`]). Returns the capture times dropped.
pub fn drop_jumps(posed: &mut BTreeMap<u64, TagPose>) -> Vec<u64> {
    let mut keys: Vec<(u64, Rigid3)> = posed.iter().map(|(t, p)| (*t, p.world_from_cam)).collect();
    let dropped = crate::poses::interp::drop_worst_jumps(&mut keys, NEIGHBOUR_S, |j| {
        (j.turn_deg / OUTLIER_DEG).max(j.moved / OUTLIER_M)
    });
    for t in &dropped {
        posed.remove(t);
    }
    dropped
}

/// Reprojection RMS of `cam_from_world` over `pairs`, normalised units (∞ behind the camera).
fn rms(cam_from_world: &Rigid3, pairs: &[Correspondence]) -> f64 {
    let mut sum = 0.0;
    for (x, obs) in pairs {
        let c = cam_from_world.transform_point(*x);
        if c.z <= 1e-9 {
            return f64::INFINITY;
        }
        sum += (DVec2::new(c.x / c.z, c.y / c.z) - *obs).length_squared();
    }
    (sum / pairs.len() as f64).sqrt()
}

/// `cam_from_world` of one square tag from its four corners by the plane-to-image homography.
fn planar_pose(corners: &[Correspondence; 4]) -> Option<Rigid3> {
    let [bl, br, _, tl] = corners.map(|c| c.0);
    let e1 = (br - bl).normalize();
    let e2 = (tl - bl - e1 * (tl - bl).dot(e1)).normalize();
    let n = e1.cross(e2);
    if !(e1.is_finite() && e2.is_finite()) {
        return None;
    }
    let world_from_plane = Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(e1, e2, n)), bl);
    let plane_from_world = world_from_plane.inverse();
    // DLT with h33 = 1: 8 equations in 8 unknowns from the 4 corners.
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for (k, (x, obs)) in corners.iter().enumerate() {
        let p = plane_from_world.transform_point(*x);
        let (u, v) = (obs.x, obs.y);
        let r = 2 * k;
        a.row_mut(r)
            .copy_from_slice(&[p.x, p.y, 1.0, 0.0, 0.0, 0.0, -u * p.x, -u * p.y]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, p.x, p.y, 1.0, -v * p.x, -v * p.y]);
        b[r] = u;
        b[r + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    let hm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    let (h1, h2, h3) = (hm.column(0), hm.column(1), hm.column(2));
    let mut lambda = 2.0 / (h1.norm() + h2.norm());
    // The tag is in front of the camera: its origin's depth is positive.
    if h3[2] * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = h1 * lambda;
    let r2 = h2 * lambda;
    let r3 = r1.cross(&r2);
    let approx = Matrix3::from_columns(&[r1, r2, r3]);
    let svd = approx.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut u = u;
        u.column_mut(2).neg_mut();
        r = u * vt;
    }
    let rot = DMat3::from_cols(
        DVec3::new(r[(0, 0)], r[(1, 0)], r[(2, 0)]),
        DVec3::new(r[(0, 1)], r[(1, 1)], r[(2, 1)]),
        DVec3::new(r[(0, 2)], r[(1, 2)], r[(2, 2)]),
    );
    let t = DVec3::new(h3[0], h3[1], h3[2]) * lambda;
    let cam_from_plane = Rigid3::new(DQuat::from_mat3(&rot), t);
    Some(cam_from_plane.compose(&plane_from_world))
}

/// Gauss–Newton (lightly damped) on the normalised reprojection error of every corner.
fn refine(start: Rigid3, pairs: &[Correspondence]) -> Rigid3 {
    let mut pose = start;
    let mut cost = rms(&pose, pairs);
    for _ in 0..20 {
        let mut jtj = Matrix6::<f64>::zeros();
        let mut jtr = Vector6::<f64>::zeros();
        for (x, obs) in pairs {
            let rx = pose.rotation * *x;
            let c = rx + pose.translation_m;
            if c.z <= 1e-9 {
                return pose;
            }
            let iz = 1.0 / c.z;
            let res = DVec2::new(c.x * iz, c.y * iz) - *obs;
            // d(proj)/dc, then dc/dω = −[Rx]×, dc/dt = I (left perturbation of the rotation).
            let du = DVec3::new(iz, 0.0, -c.x * iz * iz);
            let dv = DVec3::new(0.0, iz, -c.y * iz * iz);
            for (row, r) in [(du, res.x), (dv, res.y)] {
                let dw = rx.cross(row); // row · (−[rx]× ω) = (rx × row) · ω
                let j = Vector6::new(dw.x, dw.y, dw.z, row.x, row.y, row.z);
                jtj += j * j.transpose();
                jtr += j * r;
            }
        }
        for i in 0..6 {
            jtj[(i, i)] *= 1.0 + 1e-6;
        }
        let Some(chol) = jtj.cholesky() else {
            return pose;
        };
        let step = chol.solve(&(-jtr));
        let w = DVec3::new(step[0], step[1], step[2]);
        let next = Rigid3::new(
            DQuat::from_scaled_axis(w) * pose.rotation,
            pose.translation_m + DVec3::new(step[3], step[4], step[5]),
        );
        let next_cost = rms(&next, pairs);
        if !next_cost.is_finite() || next_cost >= cost {
            break;
        }
        let converged = cost - next_cost < 1e-12;
        pose = next;
        cost = next_cost;
        if converged {
            break;
        }
    }
    pose
}
