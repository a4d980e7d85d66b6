//! Pair consistency: is each thermal/RGB pair one rigid instant?
//!
//! A pair constrains the extrinsic only if both images saw the board at the same moment
//! through the same rigid mount. Real rigs break this: the two cameras of a dual unit are
//! triggered a few tens of milliseconds apart while the board is carried, one image is
//! re-used, or a file pairing is wrong. Such a pair pulls the joint solve (on the real
//! sun-board set, 36 pairs with some inconsistent ones left the thermal RMS at 7.9 px while
//! the thermal camera alone reaches 0.46 px). Two tests, each with a stated threshold:
//!
//! 1. **Transfer consensus, before the joint solve.** Each camera is first calibrated alone
//!    (the calibration pipeline's mono solves); each pair then gives its own extrinsic
//!    `E_i = rgb_from_board_i ∘ thermal_from_board_i⁻¹`. A candidate extrinsic `E` *transfers*
//!    pair i's RGB board pose into the thermal camera (`E⁻¹ ∘ rgb_from_board_i`) and projects
//!    the board through the thermal mono model; the pair agrees with `E` when that transfer
//!    RMS passes the residual threshold below against the RMS the thermal image reaches with
//!    its own free pose. The RGB pose carries the transfer because it is the better-pinned
//!    one (more, sharper pixels), and an error of the pose along the viewing ray (the least
//!    certain direction of a single view) barely moves the projected corners. Every `E_i`
//!    and the robust mean of all is a candidate (a RANSAC over the pairs' own hypotheses);
//!    the one most pairs agree with wins, ties to the smaller summed RMS; the consensus is
//!    then the robust mean (sign-aligned quaternion mean, component-wise median translation)
//!    of the agreeing pairs' `E_i`, re-tested twice. With fewer than 3 pairs nothing is
//!    tested. On the real sun-board set (a hand-held DJI dual camera) the pairs' own
//!    extrinsics scatter by 0.05–0.9° in rotation, several times what their corners allow:
//!    most pairs were not taken at one instant.
//! 2. **Residual, inside the joint solve.** After the joint solve, a pair whose thermal or
//!    RGB reprojection RMS exceeds `residual_ratio ×` the RMS the same image reaches with
//!    its own free pose in the mono solve, and by more than `residual_floor_px`, cannot be
//!    explained by one board pose and the common extrinsic; it is split and the joint solve
//!    repeated (at most [`MAX_RESIDUAL_ROUNDS`] rounds).
//!
//! A failing pair is not thrown away: its two images stay in the solve as separate views, so
//! each still constrains its own camera's intrinsics; only the extrinsic no longer sees it.

use glam::{DQuat, DVec2, DVec3};
use serde::Serialize;

use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;

/// Thresholds of the two tests (module docs): one residual rule for both.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PairThresholds {
    /// Transfer or joint RMS over the mono RMS of the same image that fails a pair.
    pub residual_ratio: f64,
    /// ... and by at least this much (px), so sub-pixel noise never fails a pair.
    pub residual_floor_px: f64,
}

impl Default for PairThresholds {
    fn default() -> Self {
        Self {
            residual_ratio: 3.0,
            residual_floor_px: 0.5,
        }
    }
}

/// Rounds of the residual test (each: split the failing pairs, solve again).
pub const MAX_RESIDUAL_ROUNDS: usize = 3;

/// Which test a pair failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PairTest {
    /// Failed the transfer consensus before the joint solve.
    Transfer,
    /// Failed the residual test after the joint solve.
    Residual,
}

/// A pair dropped from the extrinsic, with its figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InconsistentPair {
    /// The view key (image stem).
    pub key: String,
    pub test: PairTest,
    /// Its own extrinsic against the consensus: rotation difference (deg) ...
    pub rotation_diff_deg: f64,
    /// ... and translation difference (m; single-view depth makes this the noisier figure).
    pub translation_diff_m: f64,
    /// Thermal RMS with the RGB pose carried over by the consensus extrinsic (px).
    pub transfer_rms_px: f64,
    /// Joint-solve RMS of its thermal / RGB image (px; NaN when failed before the solve).
    pub joint_rms_px: [f64; 2],
    /// Mono-solve RMS of the same images (px).
    pub mono_rms_px: [f64; 2],
}

impl InconsistentPair {
    /// One line for the terminal and the report.
    pub fn describe(&self) -> String {
        let own = format!(
            "its own extrinsic is {:.2}° and {:.1} mm from the consensus",
            self.rotation_diff_deg,
            1e3 * self.translation_diff_m
        );
        match self.test {
            PairTest::Transfer => format!(
                "{}: its RGB pose through the consensus extrinsic puts the thermal corners {:.2} px RMS off; alone the thermal image reaches {:.2} px ({own})",
                self.key, self.transfer_rms_px, self.mono_rms_px[0]
            ),
            PairTest::Residual => format!(
                "{}: with one board pose and the common extrinsic its RMS is thermal {:.2} px, RGB {:.2} px; alone each image reaches {:.2} / {:.2} px ({own})",
                self.key,
                self.joint_rms_px[0],
                self.joint_rms_px[1],
                self.mono_rms_px[0],
                self.mono_rms_px[1]
            ),
        }
    }
}

/// Angle of the rotation between two orientations, degrees.
pub fn rotation_diff_deg(a: DQuat, b: DQuat) -> f64 {
    let d = (a * b.inverse()).normalize();
    (2.0 * d.w.abs().clamp(0.0, 1.0).acos()).to_degrees()
}

/// Robust mean of rigid transforms: sign-aligned quaternion mean, component-wise median
/// translation. The identity for an empty list.
pub fn robust_mean(ts: &[Rigid3]) -> Rigid3 {
    let Some(first) = ts.first() else {
        return Rigid3::IDENTITY;
    };
    let mut q = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    for t in ts {
        q += if t.rotation.dot(first.rotation) < 0.0 {
            -t.rotation
        } else {
            t.rotation
        };
    }
    let median = |f: fn(&Rigid3) -> f64| {
        let mut v: Vec<f64> = ts.iter().map(f).collect();
        median_in_place(&mut v)
    };
    Rigid3::new(
        q.normalize(),
        glam::DVec3::new(
            median(|t| t.translation_m.x),
            median(|t| t.translation_m.y),
            median(|t| t.translation_m.z),
        ),
    )
}

fn median_in_place(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// One pair's evidence for the transfer test.
#[derive(Debug, Clone)]
pub struct PairEvidence<'a> {
    /// `thermal_from_board` and `rgb_from_board` from the two mono solves.
    pub thermal_from_board: Rigid3,
    pub rgb_from_board: Rigid3,
    /// The thermal image's corners (canonical order).
    pub thermal_corners_px: &'a [DVec2],
    /// The board's index (into `object_points_m`) of each thermal corner.
    pub thermal_corner_ids: &'a [usize],
    /// RMS the thermal image reaches with its own free pose in the mono solve (px).
    pub thermal_mono_rms_px: f64,
}

impl PairEvidence<'_> {
    /// The pair's own extrinsic `rgb_from_thermal`.
    pub fn extrinsic(&self) -> Rigid3 {
        self.rgb_from_board
            .compose(&self.thermal_from_board.inverse())
    }

    /// RMS (px) of the thermal corners predicted through `rgb_from_thermal` from the RGB pose.
    pub fn transfer_rms_px(
        &self,
        rgb_from_thermal: &Rigid3,
        thermal: &CameraModel,
        object_points_m: &[DVec3],
    ) -> f64 {
        let thermal_from_board = rgb_from_thermal.inverse().compose(&self.rgb_from_board);
        let mut ss = 0.0;
        for (&i, obs) in self.thermal_corner_ids.iter().zip(self.thermal_corners_px) {
            let Some(x) = object_points_m.get(i) else {
                return f64::INFINITY;
            };
            match thermal.project(thermal_from_board.transform_point(*x)) {
                Some(p) => ss += (p - *obs).length_squared(),
                None => return f64::INFINITY,
            }
        }
        (ss / self.thermal_corners_px.len().max(1) as f64).sqrt()
    }
}

/// Outcome of the transfer test.
#[derive(Debug, Clone)]
pub struct TransferTest {
    /// The consensus of the pairs that agree.
    pub consensus: Rigid3,
    /// Per input pair: its transfer RMS under the consensus (px).
    pub transfer_rms_px: Vec<f64>,
    /// Per input pair: whether it agrees.
    pub agrees: Vec<bool>,
}

/// The transfer-consensus test (module docs).
pub fn transfer_test(
    pairs: &[PairEvidence],
    thermal: &CameraModel,
    object_points_m: &[DVec3],
    th: &PairThresholds,
) -> TransferTest {
    let own: Vec<Rigid3> = pairs.iter().map(PairEvidence::extrinsic).collect();
    let score = |e: &Rigid3| -> (Vec<f64>, Vec<bool>) {
        let rms: Vec<f64> = pairs
            .iter()
            .map(|p| p.transfer_rms_px(e, thermal, object_points_m))
            .collect();
        let agrees = rms
            .iter()
            .zip(pairs)
            .map(|(&r, p)| !residual_fails([r, 0.0], [p.thermal_mono_rms_px, 0.0], th))
            .collect();
        (rms, agrees)
    };
    let mean_all = robust_mean(&own);
    if pairs.len() < 3 {
        let (rms, _) = score(&mean_all);
        return TransferTest {
            consensus: mean_all,
            transfer_rms_px: rms,
            agrees: vec![true; pairs.len()],
        };
    }
    let key = |(rms, agrees): &(Vec<f64>, Vec<bool>)| {
        let n = agrees.iter().filter(|a| **a).count();
        let sum: f64 = rms
            .iter()
            .zip(agrees)
            .filter(|(_, a)| **a)
            .map(|(r, _)| *r)
            .sum();
        (n, -sum)
    };
    let mut best = (mean_all, score(&mean_all));
    for e in &own {
        let sc = score(e);
        let (n, s) = key(&sc);
        let (bn, bs) = key(&best.1);
        if n > bn || (n == bn && s > bs) {
            best = (*e, sc);
        }
    }
    // Refine: the robust mean of the agreeing pairs' own extrinsics, re-tested.
    for _ in 0..2 {
        let agreeing: Vec<Rigid3> = own
            .iter()
            .zip(&best.1.1)
            .filter(|(_, a)| **a)
            .map(|(e, _)| *e)
            .collect();
        if agreeing.is_empty() {
            break;
        }
        let e = robust_mean(&agreeing);
        let sc = score(&e);
        if key(&sc).0 < key(&best.1).0 {
            break;
        }
        best = (e, sc);
    }
    let (consensus, (transfer_rms_px, agrees)) = best;
    TransferTest {
        consensus,
        transfer_rms_px,
        agrees,
    }
}

/// The residual test for one pair: `joint` and `mono` RMS per camera `[thermal, rgb]`.
pub fn residual_fails(joint: [f64; 2], mono: [f64; 2], th: &PairThresholds) -> bool {
    joint.iter().zip(mono).any(|(&j, m)| {
        !j.is_finite() || (j > th.residual_ratio * m && j > m + th.residual_floor_px)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> CameraModel {
        CameraModel {
            width_px: 640,
            height_px: 480,
            intrinsics: crate::model::camera::Intrinsics {
                fx: 650.0,
                fy: 650.0,
                cx: 320.0,
                cy: 240.0,
            },
            distortion: crate::model::camera::BrownConrady::default(),
        }
    }

    /// A board 1.5 m in front of the thermal camera, turned by `turn` radians; RGB 65 mm to the
    /// side and rotated 1° about y; a "bad" pair's RGB view sees the board turned by its error.
    type PairData = Vec<(Rigid3, Rigid3, Vec<DVec2>)>;

    fn pairs(errors_deg: &[f64]) -> (PairData, Vec<DVec3>, Rigid3) {
        let object: Vec<DVec3> = (0..30)
            .map(|i| DVec3::new(0.1 * f64::from(i % 6), 0.1 * f64::from(i / 6), 0.0))
            .collect();
        let ext = Rigid3::new(
            DQuat::from_rotation_y(1f64.to_radians()),
            DVec3::new(-0.065, 0.0, 0.0),
        );
        let cam = camera();
        let out = errors_deg
            .iter()
            .enumerate()
            .map(|(i, &err)| {
                let turn = 0.05 * i as f64;
                let t = Rigid3::new(
                    DQuat::from_rotation_x(turn) * DQuat::from_rotation_y(-turn),
                    DVec3::new(-0.25, -0.2, 1.5),
                );
                let corners: Vec<DVec2> = object
                    .iter()
                    .filter_map(|x| cam.project(t.transform_point(*x)))
                    .collect();
                // The board moved between the two exposures: turned about the RGB camera.
                let moved = Rigid3::new(DQuat::from_rotation_y(err.to_radians()), DVec3::ZERO);
                let r = moved.compose(&ext.compose(&t));
                (t, r, corners)
            })
            .collect();
        (out, object, ext)
    }

    fn evidence<'a>(
        data: &'a PairData,
        ids: &'a [usize],
        mono_rms_px: f64,
    ) -> Vec<PairEvidence<'a>> {
        data.iter()
            .map(|(t, r, c)| PairEvidence {
                thermal_from_board: *t,
                rgb_from_board: *r,
                thermal_corners_px: c,
                thermal_corner_ids: &ids[..c.len()],
                thermal_mono_rms_px: mono_rms_px,
            })
            .collect()
    }

    #[test]
    fn pairs_off_by_a_fraction_of_a_degree_fail_and_the_rest_agree() {
        let errors = [0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.0, 0.0, -0.8, 0.0];
        let (data, object, ext) = pairs(&errors);
        let ids: Vec<usize> = (0..object.len()).collect();
        let evidence = evidence(&data, &ids, 0.3);
        let test = transfer_test(&evidence, &camera(), &object, &PairThresholds::default());
        let failed: Vec<usize> = (0..errors.len()).filter(|&i| !test.agrees[i]).collect();
        assert_eq!(
            failed,
            vec![5, 8],
            "the pairs rotated by 0.4° and 0.8° (≈4.5 and 9 px at fx 650) should fail: transfer RMS {:?}",
            test.transfer_rms_px
        );
        let off = rotation_diff_deg(test.consensus.rotation, ext.rotation);
        assert!(
            off < 1e-6,
            "consensus rotation is {off}° off the true extrinsic"
        );
    }

    #[test]
    fn perfect_pairs_all_agree() {
        let (data, object, _) = pairs(&[0.0; 6]);
        let ids: Vec<usize> = (0..object.len()).collect();
        let evidence = evidence(&data, &ids, 0.0);
        let test = transfer_test(&evidence, &camera(), &object, &PairThresholds::default());
        assert!(
            test.agrees.iter().all(|a| *a),
            "identical pairs must agree (the 0.5 px floor guards mono RMS 0): {:?}",
            test.transfer_rms_px
        );
    }

    #[test]
    fn residual_test_needs_both_ratio_and_floor() {
        let th = PairThresholds::default();
        assert!(
            residual_fails([3.0, 0.3], [0.5, 0.25], &th),
            "6x and +2.5 px fails"
        );
        assert!(
            !residual_fails([0.3, 0.3], [0.08, 0.25], &th),
            "0.3 px is under the 0.5 px floor even at 3.75x"
        );
        assert!(!residual_fails([0.9, 0.3], [0.5, 0.25], &th), "1.8x passes");
        assert!(
            residual_fails([f64::NAN, 0.3], [0.5, 0.25], &th),
            "NaN fails"
        );
    }
}
