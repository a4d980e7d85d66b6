//! Does a structure-from-motion model agree with the AprilTag map? With `--tags` on the COLMAP
//! path, every keyframe that sees enough mapped tags is also posed by PnP in the map's world.
//! Where both exist, `tag_world_from_cam · sfm_world_from_cam⁻¹` must be one and the same
//! rotation (the two worlds differ by one similarity): its spread over the keyframes measures
//! how well COLMAP's model holds together. A model hinged in two halves (what COLMAP 3.8's
//! nondeterministic matcher did about one run in three on the simulated walk when a gap left
//! too few keyframes: ±2.4°) shows as two clusters about a degree either side of the mean; a
//! sound model agrees with the tags to the tags' own PnP noise (~0.1–0.2° on the walk).
//!
//! The check reports; it does not correct (the outlier filter in [`super::sfm::drop_jumps`]
//! drops single keyframes, a hinge is the whole model). Rotation only: the centres would need
//! the scale, which is itself measured from the same tags.

use std::collections::BTreeMap;

use glam::DQuat;
use serde::Serialize;

use super::fiducials::TagPose;
use crate::model::geometry::Rigid3;

/// A keyframe whose SfM-to-tag rotation is farther than this from the common one disagrees.
pub const DISAGREE_DEG: f64 = 1.0;
/// The model is reported as disagreeing with the tags when its median keyframe is this far.
pub const MEDIAN_LIMIT_DEG: f64 = 0.5;

/// How the SfM model's keyframes agree with their tag poses.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TagAgreement {
    /// Keyframes posed both ways.
    pub keyframes: usize,
    /// Rotation of each keyframe's SfM-to-tag transform from the common one, degrees.
    pub median_deg: f64,
    pub max_deg: f64,
    /// Keyframes farther than [`DISAGREE_DEG`].
    pub disagreeing: usize,
    /// `median_deg` within [`MEDIAN_LIMIT_DEG`] and at most a tenth of the keyframes
    /// disagreeing.
    pub agrees: bool,
}

/// Compares SfM keyframe poses (capture time → world_from_cam) with tag PnP poses of the same
/// keyframes. `None` below three keyframes posed both ways.
pub fn rotation_agreement(
    sfm: &[(u64, Rigid3)],
    tags: &BTreeMap<u64, TagPose>,
) -> Option<TagAgreement> {
    // tag_world_from_sfm_world, one per keyframe posed both ways.
    let q: Vec<DQuat> = sfm
        .iter()
        .filter_map(|(t, p)| {
            let tag = tags.get(t)?;
            Some((tag.world_from_cam.rotation * p.rotation.inverse()).normalize())
        })
        .collect();
    if q.len() < 3 {
        return None;
    }
    // The medoid (least total angle to the others), then the hemisphere-aligned mean of the
    // keyframes within DISAGREE_DEG of it: a wild keyframe does not drag the common rotation.
    let medoid = *q.iter().min_by(|a, b| {
        let cost = |x: &DQuat| q.iter().map(|y| x.angle_between(*y)).sum::<f64>();
        cost(a).total_cmp(&cost(b))
    })?;
    let sum = q
        .iter()
        .filter(|x| x.angle_between(medoid).to_degrees() <= DISAGREE_DEG)
        .fold(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0), |acc, x| {
            let x = if x.dot(medoid) < 0.0 { -*x } else { *x };
            acc + x
        });
    let mean = if sum.length() > 1e-12 {
        sum.normalize()
    } else {
        medoid
    };
    let mut deg: Vec<f64> = q
        .iter()
        .map(|x| x.angle_between(mean).to_degrees())
        .collect();
    deg.sort_by(f64::total_cmp);
    let median_deg = deg[deg.len() / 2];
    let max_deg = deg[deg.len() - 1];
    let disagreeing = deg.iter().filter(|d| **d > DISAGREE_DEG).count();
    Some(TagAgreement {
        keyframes: q.len(),
        median_deg,
        max_deg,
        disagreeing,
        agrees: median_deg <= MEDIAN_LIMIT_DEG && disagreeing * 10 <= q.len(),
    })
}

#[cfg(test)]
mod tests {
    //! Proves: a model that is the tag world turned by one rotation agrees (to rounding, and
    //! to PnP-sized noise); a model hinged by 2.4° between its halves, or with one keyframe
    //! 15° off, is reported with the right counts; fewer than three common keyframes give no
    //! verdict. Does not run COLMAP (tests/tests/walk_to_model.rs checks a real model).
    #![allow(clippy::unwrap_used)]
    use super::*;
    use glam::DVec3;

    /// Keyframes along a turning path in the tag world, and the same seen from an SfM world
    /// that differs by `world` (plus `extra(i)` on keyframe i).
    fn poses(
        n: usize,
        world: DQuat,
        extra: impl Fn(usize) -> DQuat,
    ) -> (Vec<(u64, Rigid3)>, BTreeMap<u64, TagPose>) {
        let mut sfm = Vec::new();
        let mut tags = BTreeMap::new();
        for i in 0..n {
            let t = i as u64 * 100_000_000;
            let cam =
                DQuat::from_rotation_y(0.05 * i as f64) * DQuat::from_rotation_x(0.01 * i as f64);
            let centre = DVec3::new(0.1 * i as f64, 0.0, 2.0);
            tags.insert(
                t,
                TagPose {
                    world_from_cam: Rigid3::new(cam, centre),
                    rms_px: 0.3,
                    tags: 4,
                },
            );
            // sfm_world_from_cam = sfm_from_tag · tag_world_from_cam.
            let rot = (world.inverse() * cam * extra(i)).normalize();
            sfm.push((t, Rigid3::new(rot, 0.4 * centre)));
        }
        (sfm, tags)
    }

    #[test]
    fn one_rotation_between_the_worlds_agrees() {
        let world = DQuat::from_axis_angle(DVec3::new(0.3, 1.0, -0.2).normalize(), 1.1);
        let (sfm, tags) = poses(20, world, |_| DQuat::IDENTITY);
        let a = rotation_agreement(&sfm, &tags).unwrap();
        assert_eq!(a.keyframes, 20);
        assert!(a.max_deg < 1e-6 && a.agrees, "{a:?}");
        // PnP-sized noise (±0.15° about alternating axes) still agrees.
        let noise = |i: usize| {
            let axis = [DVec3::X, DVec3::Y, DVec3::Z][i % 3];
            DQuat::from_axis_angle(
                axis,
                (0.15f64 * if i.is_multiple_of(2) { 1.0 } else { -1.0 }).to_radians(),
            )
        };
        let (sfm, tags) = poses(20, world, noise);
        let a = rotation_agreement(&sfm, &tags).unwrap();
        assert!(a.agrees && a.max_deg < 0.3, "{a:?}");
    }

    #[test]
    fn a_hinged_model_and_a_wild_keyframe_are_reported() {
        let world = DQuat::from_rotation_z(0.4);
        let hinge = |i: usize| {
            if i < 10 {
                DQuat::IDENTITY
            } else {
                DQuat::from_rotation_y(2.4f64.to_radians())
            }
        };
        let (sfm, tags) = poses(20, world, hinge);
        let a = rotation_agreement(&sfm, &tags).unwrap();
        assert!(
            !a.agrees && a.median_deg > 1.0 && a.disagreeing >= 9,
            "a 2.4° hinge must show: {a:?}"
        );
        let wild = |i: usize| {
            if i == 7 {
                DQuat::from_rotation_x(15f64.to_radians())
            } else {
                DQuat::IDENTITY
            }
        };
        let (sfm, tags) = poses(20, world, wild);
        let a = rotation_agreement(&sfm, &tags).unwrap();
        assert_eq!(a.disagreeing, 1, "{a:?}");
        assert!(
            a.agrees && (a.max_deg - 15.0).abs() < 1.0,
            "one keyframe 15° off: {a:?}"
        );
        let (sfm, tags) = poses(2, world, |_| DQuat::IDENTITY);
        assert!(
            rotation_agreement(&sfm, &tags).is_none(),
            "two keyframes: no verdict"
        );
    }
}
