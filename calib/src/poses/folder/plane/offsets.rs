//! Each shot's in-plane offset (pixels in the reference orientation) from the registered pairs'
//! shifts, the GPS positions as a weak prior; pairs that disagree with the solution are dropped.
//!
//! A registered pair (i, j) says `offset[j] − offset[i] = −shift(i→j)` (the wall moves against
//! the camera); the GPS says `offset[i] ≈ scale · gps[i]` with σ = `gps_sigma_m · scale`. The
//! two image axes are independent problems of n unknowns each, solved by weighted least squares
//! (normal equations, Cholesky). Then every pair's disagreement with the solution is measured and
//! pairs beyond max(6 px, 4 × the median) are dropped, four rounds: mismatched repeated windows
//! disagree by a window's width.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};

use crate::poses::stats::median;

/// A registered pair's mean shift (pixels, b − a) between shots `i < j`.
pub type PairShifts = BTreeMap<(usize, usize), [f64; 2]>;

/// Offsets and the pairs that agree with them.
#[derive(Debug, Clone)]
pub struct Offsets {
    /// Per shot (pixels).
    pub offsets: Vec<[f64; 2]>,
    /// The pairs kept.
    pub agreeing: Vec<(usize, usize)>,
    /// Each pair's disagreement (pixels) in the last round.
    pub disagreement_px: BTreeMap<(usize, usize), f64>,
}

/// Pair weight relative to the GPS prior's (the script's 0.5 for a pair equation).
const PAIR_WEIGHT: f64 = 0.5;

/// Solves the offsets (module docs). `gps_px[i]`: the prior (scale × GPS metres in the
/// reference axes), `None` for a shot without one. Returns `None` when the system is singular
/// (shots with neither a pair nor a prior).
pub fn solve(pairs: &PairShifts, gps_px: &[Option<[f64; 2]>], sigma_px: f64) -> Option<Offsets> {
    let n = gps_px.len();
    let mut active: Vec<(usize, usize)> = pairs.keys().copied().collect();
    let mut result = None;
    for _ in 0..4 {
        let mut offsets = vec![[0.0; 2]; n];
        for axis in 0..2 {
            let mut a = DMatrix::<f64>::zeros(n, n);
            let mut b = DVector::<f64>::zeros(n);
            let wp = PAIR_WEIGHT * PAIR_WEIGHT;
            for &(i, j) in &active {
                let t = pairs[&(i, j)][axis];
                // offset[j] − offset[i] = −t
                a[(i, i)] += wp;
                a[(j, j)] += wp;
                a[(i, j)] -= wp;
                a[(j, i)] -= wp;
                b[j] += -t * wp;
                b[i] -= -t * wp;
            }
            let wg = 1.0 / (sigma_px * sigma_px);
            for (i, g) in gps_px.iter().enumerate() {
                if let Some(g) = g {
                    a[(i, i)] += wg;
                    b[i] += g[axis] * wg;
                }
            }
            let x = a.cholesky()?.solve(&b);
            for i in 0..n {
                offsets[i][axis] = x[i];
            }
        }
        let disagreement: BTreeMap<(usize, usize), f64> = pairs
            .iter()
            .map(|(&(i, j), t)| {
                let d = [
                    offsets[j][0] - offsets[i][0] + t[0],
                    offsets[j][1] - offsets[i][1] + t[1],
                ];
                ((i, j), d[0].hypot(d[1]))
            })
            .collect();
        let ds: Vec<f64> = disagreement.values().copied().collect();
        let threshold = (4.0 * median(&ds)).max(6.0);
        active = disagreement
            .iter()
            .filter(|(_, d)| **d < threshold)
            .map(|(k, _)| *k)
            .collect();
        result = Some(Offsets {
            offsets,
            agreeing: active.clone(),
            disagreement_px: disagreement,
        });
    }
    result
}

#[cfg(test)]
mod tests {
    #![allow(clippy::expect_used)]

    use super::*;

    #[test]
    fn offsets_follow_the_pairs_and_a_wrong_pair_is_dropped() {
        // Ten shots in a row 200 px apart, each registered with its next three; GPS off by up
        // to 60 px; one pair matched a repeated window 150 px away.
        let n = 10;
        let truth: Vec<f64> = (0..n).map(|i| 200.0 * i as f64).collect();
        let gps: Vec<f64> = (0..n)
            .map(|i| truth[i] + [30.0, -60.0, 60.0, -40.0, 30.0][i % 5])
            .collect();
        let mut pairs = PairShifts::new();
        for i in 0..n {
            for j in i + 1..(i + 4).min(n) {
                pairs.insert((i, j), [-(truth[j] - truth[i]), 0.0]);
            }
        }
        pairs.insert((4, 5), [-(200.0 + 150.0), 0.0]);
        let prior: Vec<Option<[f64; 2]>> = gps.iter().map(|&g| Some([g, 0.0])).collect();
        let o = solve(&pairs, &prior, 0.5 * 215.0).expect("solvable");
        assert!(
            !o.agreeing.contains(&(4, 5)),
            "the wrong pair is dropped: {:?}",
            o.agreeing
        );
        assert_eq!(o.agreeing.len(), pairs.len() - 1, "every right pair kept");
        for i in 1..n {
            let rel = (o.offsets[i][0] - o.offsets[0][0]) - (truth[i] - truth[0]);
            assert!(rel.abs() < 1.0, "shot {i} relative offset off by {rel} px");
        }
    }

    #[test]
    fn a_shot_with_neither_pair_nor_prior_is_singular() {
        let mut pairs = PairShifts::new();
        pairs.insert((0, 1), [10.0, 0.0]);
        assert!(solve(&pairs, &[Some([0.0; 2]), None, None], 100.0).is_none());
    }
}
