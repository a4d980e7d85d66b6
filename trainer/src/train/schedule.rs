//! What changes with the run's progress: the warm-up's end, learning rates, loss weights,
//! when density control runs, and the consistency pairing of each step.
//!
//! # Iterations or a wall-clock budget
//! The schedule is written in iterations of a nominal run of `iters` (the paper's 30 000:
//! warm-up 3 000, densification from 500 to 15 000, the position learning rate decaying over
//! the whole run). Without a time budget the run is that many iterations. With
//! `time_budget_s` the run stops when its training time (step time, as the error-vs-time plots
//! count it: held-out evaluations and checkpoints excluded) reaches the budget, and the
//! schedule follows the fraction of the budget spent instead: at 10 % of the time the warm-up
//! ends, densification stops at half the time, the learning rate decays to its final value
//! at the end, and a capacity check runs each time the schedule passes another
//! `capacity.every`. The other cadences (`densify.every`, `consist_every`) stay in real
//! iterations: they are about how many views a statistic averages, not about the run's length.
//!
//! # Bringing the bands in
//! At the warm-up's end every band slot of every primitive goes live at once (amplitude 0, a
//! random frequency and phase) on a scene the Gaussians already fit, as in the paper. With
//! `band_ramp` > 0 their learning rates instead rise linearly from 0 over that many iterations
//! of the nominal run, as 3DGS brings in its SH degrees one at a time (a run without a warm-up
//! trains its bands at full rate from the start). Off by default, by measurement: on the real
//! facade (8-minute budget, two seeds) a ramp as long as the warm-up ended 0.13–0.14 dB below
//! the bands at once; on the simulated scenes the two are within their noise. What the
//! facade's drop after the warm-up came from was Adam's bias corrections (see `adam`).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::init::draw_band;
use super::{
    AdamParams, Backend, ConsistPartner, GroupLrs, PairChoice, TrainConfig, Trainer, params,
};
use crate::loss::LossWeights;
use crate::primitive::{BETA_RAW_GAUSSIAN, is_beta_frozen};

/// The fewest band-amplitude steps the band grant ranks by (see [`Trainer::grant_due`]).
pub(super) const GRANT_MIN_STEPS: u64 = 20;

impl TrainConfig {
    /// Training seconds at which this schedule's warm-up ends, for readers of a finished run
    /// (`compare`): with a time budget the fraction `warmup / iters` of it (the schedule's
    /// mapping, [`Trainer::progress`]); otherwise the first of the run's `evaluations`
    /// (iteration, training seconds) at or after the warm-up's iteration. `None` when neither
    /// says.
    pub fn warmup_end_s(&self, evaluations: impl IntoIterator<Item = (u64, f64)>) -> Option<f64> {
        match self.time_budget_s {
            Some(budget) if self.iters > 0 => Some(budget * self.warmup as f64 / self.iters as f64),
            Some(_) => None,
            None => evaluations
                .into_iter()
                .find(|&(iteration, _)| iteration >= self.warmup)
                .map(|(_, seconds)| seconds),
        }
    }
}

impl<B: Backend> Trainer<B> {
    /// How far the run is, 0…1: iterations done of `iters`, or with a time budget the
    /// training seconds spent of it.
    pub fn progress(&self) -> f64 {
        let p = match self.cfg.time_budget_s {
            Some(budget) => self.train_seconds / budget,
            None => self.iteration as f64 / self.cfg.iters.max(1) as f64,
        };
        p.clamp(0.0, 1.0)
    }

    /// Where the schedule is, in iterations of the nominal `iters`-long run: the iteration
    /// itself, or with a time budget the same fraction of `iters` as of the budget spent.
    pub(super) fn schedule_iteration(&self) -> u64 {
        match self.cfg.time_budget_s {
            Some(_) => (self.progress() * self.cfg.iters as f64) as u64,
            None => self.iteration,
        }
    }

    /// The run is over: `iters` iterations done, or the time budget spent.
    pub fn finished(&self) -> bool {
        match self.cfg.time_budget_s {
            Some(budget) => self.train_seconds >= budget,
            None => self.iteration >= self.cfg.iters,
        }
    }

    /// The iteration at which the warm-up ended (`None`: not yet).
    pub fn warmup_ended_at(&self) -> Option<u64> {
        self.state.warmup_ended_at
    }

    pub(super) fn after_warmup(&self) -> bool {
        self.schedule_iteration() >= self.cfg.warmup
    }

    /// Density control runs after this step: every `densify.every` iterations while the
    /// schedule is in `[from, min(until, iters/2))` (3DGS: 15 000 of 30 000, so the last
    /// primitives added have the second half of the run to settle).
    pub(super) fn densify_due(&self) -> bool {
        let d = self.cfg.densify;
        let at = self.schedule_iteration();
        d.every > 0
            && at >= d.from
            && at < d.until.min(self.cfg.iters / 2)
            && self.iteration.is_multiple_of(d.every)
    }

    /// The band grant runs after this step: once, when the band amplitudes have trained for
    /// one pass over the training views (at least [`GRANT_MIN_STEPS`] steps), so that Adam's
    /// second moment of every amplitude has averaged its gradient over the views (see
    /// `bands`).
    pub(super) fn grant_due(&self) -> bool {
        self.prims.bands > 0
            && !self.bands_granted()
            && self.adam.group_steps.band_amp >= (self.data.train.len() as u64).max(GRANT_MIN_STEPS)
    }

    /// Capacity adaptation runs after this step, in modes with bands or learnable β: every
    /// `capacity.every` iterations counted from the warm-up's end, or with a time budget each
    /// time the schedule passes another `capacity.every` of the nominal run (so a short
    /// budgeted run still drops its negligible bands: ~27 checks whatever its speed).
    pub(super) fn capacity_due(&self) -> bool {
        let c = self.cfg.capacity;
        let Some(w) = self.state.warmup_ended_at else {
            return false;
        };
        if !(self.prims.bands > 0 || self.cfg.mode.learns_beta()) || c.every == 0 {
            return false;
        }
        match self.cfg.time_budget_s {
            Some(_) => {
                let since = self.schedule_iteration().saturating_sub(self.cfg.warmup);
                since / c.every > self.state.capacity_checks
            }
            None => self.iteration > w && (self.iteration - w).is_multiple_of(c.every),
        }
    }

    /// Adam's hyper-parameters for the primitives, with the run's band L1 λ.
    pub(super) fn adam_params(&self) -> AdamParams {
        AdamParams {
            band_l1: self.cfg.capacity.band_l1,
            ..AdamParams::default()
        }
    }

    pub(super) fn lrs(&self) -> GroupLrs {
        let mut lr = self.cfg.lr;
        let t = self.progress();
        lr.means *= self.extent_m * self.cfg.means_lr_final_ratio.powf(t);
        let warm = self.after_warmup();
        if !(self.cfg.mode.learns_beta() && warm) {
            lr.beta = 0.0;
        }
        let bands = if self.prims.bands > 0 && warm {
            self.band_ramp()
        } else {
            0.0
        };
        lr.band_amp *= bands;
        lr.band_freq *= bands;
        lr.band_phase *= bands;
        lr
    }

    /// The bands' share of their learning rates after the warm-up: rising linearly from the
    /// warm-up's end to 1 after `band_ramp` iterations of the nominal run (see the module docs).
    fn band_ramp(&self) -> f64 {
        let ramp = self.cfg.band_ramp;
        if ramp == 0 || self.cfg.warmup == 0 {
            return 1.0;
        }
        let since = self.schedule_iteration().saturating_sub(self.cfg.warmup) + 1;
        (since as f64 / ramp as f64).min(1.0)
    }

    pub(super) fn loss_weights(&self) -> LossWeights {
        let warm = self.after_warmup();
        LossWeights {
            lambda_dssim: self.cfg.weights.dssim,
            lambda_consist: self.cfg.weights.consist,
            lambda_sparse: if warm && self.cfg.sparse && self.prims.bands > 0 {
                self.cfg.weights.sparse
            } else {
                0.0
            },
            lambda_smooth: if warm && self.cfg.smooth && self.beta_live() {
                self.cfg.weights.smooth
            } else {
                0.0
            },
        }
    }

    /// Some primitive's β is still learnable (a mode that learns β, and not every primitive
    /// snapped to the Gaussian path). Frozen β is a sentinel only the host writes, so the host's
    /// copy answers even while the parameters live on the device.
    pub(super) fn beta_live(&self) -> bool {
        self.cfg.mode.learns_beta()
            && self
                .prims
                .beta_raw
                .iter()
                .any(|&r| !is_beta_frozen(f64::from(r)))
    }

    /// Some primitive is off the Gaussian path (band storage, or a learnable β). Once none is,
    /// Ψ_high = 0 and Ψ_β = 2·alpha: the consistency and smoothness terms, whose job is the
    /// frequency maps, would only pull on the opacities (a blur 3dgs mode does not have), so
    /// they stop and the run goes on as a Gaussian one — the guard's "3dgs pace" (issue 42).
    pub(super) fn spectral_live(&self) -> bool {
        self.prims.bands > 0 || self.beta_live()
    }

    pub(super) fn consist_active(&self) -> bool {
        self.cfg.consist
            && self.after_warmup()
            && self.spectral_live()
            && self.cfg.consist_every > 0
            && self.iteration.is_multiple_of(self.cfg.consist_every)
    }

    /// The view of a step and its consistency partner, from the view `drawn` at random (see
    /// [`ConsistPartner`]): with [`ConsistPartner::Previous`], a step that follows a step
    /// without a term (on view i, whose G-buffers are kept) trains one of i's overlapping
    /// views j, drawn from `rng`, against them instead of `drawn`.
    pub(super) fn schedule(
        &self,
        drawn: usize,
        rng: &mut ChaCha8Rng,
    ) -> (usize, Option<PairChoice>) {
        if !self.consist_active() {
            return (drawn, None);
        }
        match self.cfg.consist_partner {
            ConsistPartner::Render => (drawn, self.pairs[drawn].map(PairChoice::Render)),
            ConsistPartner::Previous => match &self.kept {
                // One of i's overlapping views at random, not i's best partner: views that are
                // nobody's best partner would otherwise train only on lead steps.
                Some(k) if !k.followed && k.iteration + 1 == self.iteration => {
                    match self.neighbours[k.view].as_slice() {
                        [] => (drawn, None),
                        near => (
                            near[rng.random_range(0..near.len())],
                            Some(PairChoice::Previous(k.view)),
                        ),
                    }
                }
                _ => (drawn, None),
            },
        }
    }

    /// End of the warm-up: the band storage grows to `m` slots per primitive (the warm-up ran
    /// without it), and every slot goes live with amplitude 0 and a frequency and phase drawn
    /// as at initialisation, from the primitive's mean scale now (primitives have grown,
    /// shrunk and split since); the outputs do not change, and from now on the bands train.
    pub(super) fn release_warmup_bands(&mut self, m: usize) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        if self.prims.bands < m {
            let none = vec![Vec::new(); self.prims.len()];
            for p in [&mut self.prims, &mut self.adam.m, &mut self.adam.v] {
                *p = params::compact_bands(p, &none, m);
            }
        }
        let m = self.prims.bands;
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ 0xba4d_5eed ^ self.iteration);
        for i in 0..self.prims.len() {
            let sc = self.prims.scales(i);
            let s = f64::from(sc[0] + sc[1] + sc[2]) / 3.0;
            for j in 0..m {
                let k = m * i + j;
                let (freq, phase) = draw_band(&mut rng, s.max(1e-9));
                self.prims.band_amp[k] = 0.0;
                for (dst, f) in self.prims.band_freq[3 * k..3 * k + 3].iter_mut().zip(freq) {
                    *dst = f as f32;
                }
                self.prims.band_phase[k] = phase as f32;
            }
        }
        for p in [&mut self.prims, &mut self.adam.m, &mut self.adam.v] {
            p.band_count.fill(m as u32);
        }
        tracing::debug!(iteration = self.iteration, "warm-up over: bands live");
    }

    /// End of the warm-up: every frozen β becomes learnable (β = 2 + 4.5e-5).
    pub(super) fn release_warmup_beta(&mut self) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let mut released = 0;
        for (r, (m, v)) in self.prims.beta_raw.iter_mut().zip(
            self.adam
                .m
                .beta_raw
                .iter_mut()
                .zip(&mut self.adam.v.beta_raw),
        ) {
            if is_beta_frozen(f64::from(*r)) {
                *r = BETA_RAW_GAUSSIAN as f32;
                (*m, *v) = (0.0, 0.0);
                released += 1;
            }
        }
        tracing::debug!(
            iteration = self.iteration,
            released,
            "warm-up over: β learnable"
        );
    }
}
