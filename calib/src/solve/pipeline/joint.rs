//! The pair tests around the joint solve: the transfer test on the mono poses picks the pairs
//! that constrain the extrinsic and its starting value; the joint solve then runs in rounds,
//! each ending with the residual test, until no further pair fails
//! ([`crate::solve::pairs`]).

use glam::DVec3;

use super::solves::{MonoSolve, joint_problem, view_rms};
use crate::detect::views::DetectedSet;
use crate::model::geometry::Rigid3;
use crate::solve::lm::{Problem, SolveOptions, SolveReport, solve};
use crate::solve::pairs::{
    InconsistentPair, MAX_RESIDUAL_ROUNDS, PairEvidence, PairTest, PairThresholds, residual_fails,
    rotation_diff_deg, transfer_test,
};

/// The pairs of a set (views with the board in both cameras) and the tests' verdicts.
#[derive(Debug)]
pub(super) struct Pairs {
    /// Per set view: seen by both cameras' mono solves.
    pub(super) is_pair: Vec<bool>,
    pub(super) pair_views: Vec<usize>,
    /// Per set view: left out of the extrinsic (its cameras' views solved apart).
    pub(super) split: Vec<bool>,
    pub(super) inconsistent: Vec<InconsistentPair>,
    /// The extrinsic the next joint solve starts from.
    pub(super) rgb_from_thermal: Option<Rigid3>,
}

/// The last round of the joint solve.
#[derive(Debug)]
pub(super) struct Joint {
    pub(super) problem: Problem,
    /// Keys of the views in solver order.
    pub(super) view_keys: Vec<String>,
    pub(super) report: SolveReport,
    pub(super) pairs_used: usize,
}

/// Test 1 (pose difference, the transfer test) on the mono poses: the pairs that disagree with
/// the consensus are split, and the consensus starts the joint solve.
pub(super) fn transfer_pairs(
    set: &DetectedSet,
    object: &[DVec3],
    mono: &[Option<MonoSolve>; 2],
    thresholds: &PairThresholds,
) -> Pairs {
    let is_pair: Vec<bool> = (0..set.views.len())
        .map(|v| match mono {
            [Some(t), Some(r)] => t.pose(v).is_some() && r.pose(v).is_some(),
            _ => false,
        })
        .collect();
    let pair_views: Vec<usize> = (0..set.views.len()).filter(|&v| is_pair[v]).collect();
    let mut pairs = Pairs {
        split: vec![false; set.views.len()],
        is_pair,
        pair_views,
        inconsistent: Vec::new(),
        rgb_from_thermal: None,
    };
    let [Some(mt), Some(mr)] = mono else {
        return pairs;
    };
    let mut used = Vec::new();
    let evidence: Vec<PairEvidence> = pairs
        .pair_views
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
    let test = transfer_test(&evidence, &mt.model, object, thresholds);
    for (i, &v) in used.iter().enumerate() {
        if test.agrees[i] {
            continue;
        }
        pairs.split[v] = true;
        let own = evidence[i].extrinsic();
        pairs.inconsistent.push(InconsistentPair {
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
        pairs.rgb_from_thermal = Some(test.consensus);
    }
    pairs
}

/// The joint solve; test 2 (residual) on its result, splitting failing pairs and solving
/// again from this round's extrinsic, for at most [`MAX_RESIDUAL_ROUNDS`] tested rounds.
pub(super) fn joint_rounds(
    set: &DetectedSet,
    object: &[DVec3],
    mono: &[Option<MonoSolve>; 2],
    pairs: &mut Pairs,
    opts: &SolveOptions,
    thresholds: &PairThresholds,
) -> Joint {
    let mut round = 0;
    loop {
        let (mut problem, view_keys, source, pairs_used) =
            joint_problem(set, object, mono, &pairs.split, pairs.rgb_from_thermal);
        let report = solve(&mut problem, opts);
        round += 1;
        let mut newly = Vec::new();
        if let [Some(mt), Some(mr)] = mono
            && round <= MAX_RESIDUAL_ROUNDS
            && problem.rgb_from_thermal.is_some()
        {
            newly = residual_test(set, &problem, &source, [mt, mr], pairs, thresholds);
        }
        if newly.is_empty() {
            return Joint {
                problem,
                view_keys,
                report,
                pairs_used,
            };
        }
        for v in newly {
            pairs.split[v] = true;
        }
        // The next round starts from this round's extrinsic.
        pairs.rgb_from_thermal = problem.rgb_from_thermal;
    }
}

/// The residual test on one round's joint solution: each pair still in the extrinsic whose
/// joint RMS the mono RMS does not explain is recorded as inconsistent; returns those views.
fn residual_test(
    set: &DetectedSet,
    problem: &Problem,
    source: &[usize],
    [mt, mr]: [&MonoSolve; 2],
    pairs: &mut Pairs,
    thresholds: &PairThresholds,
) -> Vec<usize> {
    let mut newly = Vec::new();
    let per_view = view_rms(problem);
    for (pv, &v) in source.iter().enumerate() {
        if pairs.split[v] || !pairs.is_pair[v] {
            continue;
        }
        let joint = [per_view[pv][0], per_view[pv][1]];
        let mono_rms = [mt.view_rms(v), mr.view_rms(v)];
        if residual_fails(joint, mono_rms, thresholds) {
            let ext = problem.rgb_from_thermal.unwrap_or(Rigid3::IDENTITY);
            let own = match (mt.pose(v), mr.pose(v)) {
                (Some(t), Some(r)) => r.compose(&t.inverse()),
                _ => ext,
            };
            newly.push(v);
            pairs.inconsistent.push(InconsistentPair {
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
    newly
}
