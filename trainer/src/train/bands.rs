//! Bands only where the data needs them: the band grant, the periodic drop of negligible
//! bands and the compaction of the band storage (capacity adaptation's band part; the report
//! is `capacity`).
//!
//! # How
//! At the warm-up's end every band slot goes live at amplitude 0 (`schedule`). For one pass over
//! the training views (at least 20 steps; `schedule::grant_due`) Adam's second moment of each
//! amplitude averages the squared gradient `∂L/∂ω_j`: the projection of the residual, through
//! the primitive's footprint, onto the band's carrier `cos(2π f_j·x + φ_j)`. A large RMS
//! gradient says the residual under the primitive has energy at a frequency the Gaussian
//! cannot fit and a band there would reduce the loss; a small one says the band has nothing
//! to fit. Then, once ([`Trainer::grant_bands`]), a primitive keeps its bands only when
//! one of them has an RMS gradient above `band_l1` λ (the first-order condition under which
//! the amplitudes' proximal L1 step, `train::adam`, lets an amplitude leave zero), ranked by
//! that gradient and at most `band_budget` of the primitives; the others lose their band slots
//! (and return to the Gaussian path when their β is near 2). When no primitive qualifies, the
//! scene does not need bands: the band storage compacts to M = 0 and the run goes on at the
//! speed of a band-free mode, saying so. Later, the L1 step takes unused amplitudes to exactly
//! zero and the periodic check drops them. Every round is in `capacity.json`'s `band_rounds`.

use serde::{Deserialize, Serialize};

use super::{Backend, Trainer, params};

impl<B: Backend> Trainer<B> {
    /// The band grant has run.
    pub(super) fn bands_granted(&self) -> bool {
        let rounds = &self.state.capacity.band_rounds;
        rounds.iter().any(|r| r.kind == BandRoundKind::Grant)
    }

    /// The band grant, once after the warm-up: keeps bands only on the primitives whose
    /// residual they can fit (see the module docs); [`Self::drop_bands`] then compacts the
    /// storage.
    pub(super) fn grant_bands(&mut self) {
        let steps = self.adam.group_steps.band_amp;
        if steps == 0 {
            // No amplitude gradient measured yet (learning rate 0 so far): nothing to rank by.
            return;
        }
        self.kept = None;
        let m = self.prims.bands;
        let n = self.prims.len();
        let correction = 1.0 - self.adam_params().beta2.powf(steps as f64);
        let scores: Vec<f64> = (0..n)
            .map(|i| {
                (0..self.prims.live_bands(i))
                    .map(|j| (f64::from(self.adam.v.band_amp[m * i + j]) / correction).sqrt())
                    .fold(0.0, f64::max)
            })
            .collect();
        let holders_before = (0..n).filter(|&i| self.prims.live_bands(i) > 0).count();
        let cap = self.cfg.capacity;
        let budget = ((cap.band_budget.clamp(0.0, 1.0) * n as f64).floor() as usize).min(n);
        let granted = band_grant(&scores, cap.band_l1, budget);
        self.refuse_bands(&granted);
        let kept = granted.iter().filter(|&&g| g).count();
        let over_threshold = scores.iter().filter(|&&s| s > cap.band_l1).count();
        let mut sorted = scores.clone();
        sorted.sort_by(f64::total_cmp);
        let quantile = |q: f64| sorted.get(((n as f64 - 1.0) * q).round() as usize).copied();
        let round = BandRound {
            iteration: self.iteration,
            seconds: self.train_seconds,
            kind: BandRoundKind::Grant,
            holders_before,
            holders_after: kept,
            over_threshold,
            budget,
            rms_gradient_median: quantile(0.5).unwrap_or(0.0),
            rms_gradient_p90: quantile(0.9).unwrap_or(0.0),
            rms_gradient_max: quantile(1.0).unwrap_or(0.0),
            bands_dropped: 0,
        };
        tracing::info!(
            iteration = self.iteration,
            granted = kept,
            of = n,
            over_threshold,
            budget,
            median = round.rms_gradient_median,
            p90 = round.rms_gradient_p90,
            max = round.rms_gradient_max,
            "bands granted where the residual needs them"
        );
        if kept == 0 && holders_before > 0 {
            self.state.capacity.notes.push(format!(
                "bands left out at iteration {}: no primitive's band gradient exceeded λ = {} \
                 (RMS gradient max {:.3e}); the run goes on without bands",
                self.iteration, cap.band_l1, round.rms_gradient_max
            ));
        }
        self.state.capacity.band_rounds.push(round);
    }

    /// Marks every band slot of the primitives with `keep[i]` false dropped (the next
    /// [`Self::drop_bands`] removes them).
    fn refuse_bands(&mut self, keep: &[bool]) {
        self.kept = None;
        for (i, _) in keep.iter().enumerate().filter(|(_, k)| !**k) {
            for p in [&mut self.prims, &mut self.adam.m, &mut self.adam.v] {
                if let Some(c) = p.band_count.get_mut(i) {
                    *c = 0;
                }
            }
        }
    }

    /// Leaves bands only on the primitives with `keep[i]` true and compacts the band storage,
    /// as the band grant does, then snaps the band-free primitives whose β is near 2 to the
    /// Gaussian path as the next capacity check does (for benchmarks of the state they leave —
    /// with no holder, a scene like the real facade at its end; a run's own grant is
    /// [`Self::grant_bands`]).
    pub fn keep_bands_on(&mut self, keep: &[bool]) {
        self.refuse_bands(keep);
        self.compact_bands(0.0);
        if self.cfg.mode.learns_beta() {
            self.freeze_gaussians();
        }
    }

    /// Drops negligible bands per primitive and compacts the band storage.
    pub(super) fn drop_bands(&mut self) {
        self.compact_bands(self.cfg.capacity.band_amp_threshold as f32);
    }

    /// Drops the live bands with `|ω| < thr` per primitive and compacts the band storage.
    fn compact_bands(&mut self, thr: f32) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let m = self.prims.bands;
        let mut keep: Vec<Vec<usize>> = Vec::with_capacity(self.prims.len());
        let mut dropped = 0;
        let holders_before = (0..self.prims.len())
            .filter(|&i| self.prims.live_bands(i) > 0)
            .count();
        for i in 0..self.prims.len() {
            let mut live: Vec<usize> = (0..self.prims.live_bands(i))
                .filter(|&j| self.prims.band_amp[m * i + j].abs() >= thr)
                .collect();
            live.sort_by(|&a, &b| {
                self.prims.band_amp[m * i + b]
                    .abs()
                    .total_cmp(&self.prims.band_amp[m * i + a].abs())
            });
            dropped += self.prims.live_bands(i) - live.len();
            keep.push(live);
        }
        let new_m = keep.iter().map(Vec::len).max().unwrap_or(0);
        let before = self.state.step_ms_sum / self.state.step_count.max(1) as f64;
        self.prims = params::compact_bands(&self.prims, &keep, new_m);
        self.adam.m = params::compact_bands(&self.adam.m, &keep, new_m);
        self.adam.v = params::compact_bands(&self.adam.v, &keep, new_m);
        let cap = &mut self.state.capacity;
        cap.bands_dropped_total = dropped;
        if let Some(last) = cap
            .band_rounds
            .last_mut()
            .filter(|r| r.iteration == self.iteration)
        {
            last.bands_dropped += dropped;
            last.holders_after = keep.iter().filter(|k| !k.is_empty()).count();
        } else if dropped > 0 {
            cap.band_rounds.push(BandRound {
                iteration: self.iteration,
                seconds: self.train_seconds,
                kind: BandRoundKind::Drop,
                holders_before,
                holders_after: keep.iter().filter(|k| !k.is_empty()).count(),
                bands_dropped: dropped,
                ..BandRound::default()
            });
        }
        if new_m < m {
            cap.step_ms_before_compaction = Some(before);
            cap.step_ms_after_compaction = None;
            self.state.step_ms_sum = 0.0;
            self.state.step_count = 0;
            tracing::info!(
                iteration = self.iteration,
                from = m,
                to = new_m,
                "band storage compacted"
            );
        }
        cap.bands_now = new_m;
    }
}

/// What a capacity check did to the bands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BandRoundKind {
    /// The first check after the warm-up: bands kept only where they pay.
    #[default]
    Grant,
    /// A later check that dropped negligible bands.
    Drop,
}

/// One capacity check's effect on the bands (`capacity.json`'s `band_rounds`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BandRound {
    pub iteration: u64,
    /// Training seconds when the check ran.
    pub seconds: f64,
    pub kind: BandRoundKind,
    /// Primitives with a live band before and after the check.
    pub holders_before: usize,
    pub holders_after: usize,
    /// Grant: primitives whose largest band RMS gradient exceeded λ (`band_l1`).
    pub over_threshold: usize,
    /// Grant: the most primitives that may keep bands (`band_budget` of them).
    pub budget: usize,
    /// Grant: quantiles of the primitives' largest band RMS gradient (loss units per unit of
    /// amplitude), to choose λ by.
    pub rms_gradient_median: f64,
    pub rms_gradient_p90: f64,
    pub rms_gradient_max: f64,
    /// Band slots dropped by the check (amplitude below `band_amp_threshold`, after the grant).
    pub bands_dropped: usize,
}

/// Which primitives keep their bands: those with `scores[i] > threshold`, highest first, at
/// most `budget` of them.
pub fn band_grant(scores: &[f64], threshold: f64, budget: usize) -> Vec<bool> {
    let mut order: Vec<usize> = (0..scores.len())
        .filter(|&i| scores[i] > threshold)
        .collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    let mut out = vec![false; scores.len()];
    for &i in order.iter().take(budget) {
        out[i] = true;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::band_grant;

    #[test]
    fn the_grant_keeps_the_largest_gradients_over_the_threshold_within_the_budget() {
        let scores = [0.5, 3.0, 0.05, 2.0, 1.0, 0.2];
        assert_eq!(
            band_grant(&scores, 0.3, 2),
            [false, true, false, true, false, false],
            "budget 2: the two largest"
        );
        assert_eq!(
            band_grant(&scores, 0.3, 6),
            [true, true, false, true, true, false],
            "no budget: every score over 0.3"
        );
        assert_eq!(
            band_grant(&scores, 5.0, 6),
            [false; 6],
            "none over the threshold: no bands at all"
        );
    }
}
