//! Capacity adaptation's report (what the run left out and what it saved) and its Gaussian
//! path (snapping Gaussian-like primitives to the cheap path); the bands' part is `bands`.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::bands::BandRound;
use super::density::DensifyRound;
use super::{Backend, TrainError, Trainer};
use crate::primitive::{BETA_RAW_FROZEN, beta_of_raw, is_beta_frozen};
use crate::render::GBuffers;

impl<B: Backend> Trainer<B> {
    pub(super) fn initial_capacity(&self) -> CapacityReport {
        let pairs = self.pairs.iter().filter(|p| p.is_some()).count();
        let has_rgb = self.data.has_rgb();
        let mut notes = Vec::new();
        if !self.data.undistorted_models.is_empty() {
            notes.push(format!(
                "undistorted at load: {}",
                self.data.undistorted_models.join(", ")
            ));
        }
        CapacityReport {
            mode: self.cfg.mode.to_string(),
            colour_allocated: has_rgb,
            colour_reason: if has_rgb {
                "the dataset has RGB views".into()
            } else {
                "no RGB views: no SH colour allocated".into()
            },
            consistency_pairs: pairs,
            consistency_reason: if !self.cfg.consist {
                "disabled (--no-consist)".into()
            } else if !(self.cfg.mode.learns_beta() || self.cfg.mode.has_bands()) {
                "not needed: Ψ_high and Ψ_β are constant in this mode".into()
            } else if pairs == 0 {
                "skipped: no view pair overlaps enough".into()
            } else {
                format!("{pairs} views have an overlap partner")
            },
            // The warm-up runs without band storage (`init`): the run's M is the config's.
            bands_initial: if self.cfg.mode.has_bands() {
                self.cfg.bands.max(self.prims.bands)
            } else {
                self.prims.bands
            },
            bands_now: self.prims.bands,
            rgb_loss: self.rgb_loss_choice().map(|(_, why)| why),
            thermal_align: self.thermal_align_setting(),
            notes,
            ..CapacityReport::default()
        }
    }

    /// Snaps primitives with β ≤ `gaussian_beta_max` and no live band to β = 2, frozen.
    pub(super) fn freeze_gaussians(&mut self) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let max = self.cfg.capacity.gaussian_beta_max;
        let mut frozen = 0;
        for i in 0..self.prims.len() {
            let raw = f64::from(self.prims.beta_raw[i]);
            if !is_beta_frozen(raw) && beta_of_raw(raw).0 <= max && self.prims.live_bands(i) == 0 {
                self.prims.beta_raw[i] = BETA_RAW_FROZEN as f32;
                self.adam.m.beta_raw[i] = 0.0;
                self.adam.v.beta_raw[i] = 0.0;
                frozen += 1;
            }
        }
        self.state.capacity.gaussian_frozen_last_check = frozen;
        tracing::debug!(
            iteration = self.iteration,
            frozen,
            "β snapped to 2 (Gaussian path)"
        );
    }

    /// After a capacity check: the first time no primitive is left off the Gaussian path (no
    /// band storage, every β frozen at 2) in a mode that had one, says so; from then on the
    /// consistency and smoothness terms are off (`schedule::spectral_live`).
    pub(super) fn note_gaussian_run(&mut self) {
        let spectral_mode = self.cfg.mode.learns_beta() || self.cfg.mode.has_bands();
        if !spectral_mode || self.spectral_live() || self.state.capacity.gaussian_from.is_some() {
            return;
        }
        let at = GaussianFrom {
            iteration: self.iteration,
            seconds: self.train_seconds,
        };
        tracing::info!(
            iteration = at.iteration,
            "every primitive on the Gaussian path: consistency and smoothness terms off"
        );
        self.state.capacity.notes.push(format!(
            "every primitive on the Gaussian path from iteration {} ({:.0} s): no band and no \
             learnable β left, so the consistency and smoothness terms are off and the run goes on \
             as 3dgs mode",
            at.iteration, at.seconds
        ));
        self.state.capacity.gaussian_from = Some(at);
    }

    /// The capacity report as of now.
    pub fn capacity_report(&self) -> CapacityReport {
        let mut cap = self.state.capacity.clone();
        let m = self.prims.bands;
        cap.bands_now = m;
        cap.primitives = self.prims.len();
        cap.memory_bytes = self.memory_bytes();
        let rounds = &cap.densify_rounds;
        cap.densify_cloned = rounds.iter().map(|r| r.cloned).sum();
        cap.densify_split = rounds.iter().map(|r| r.split).sum();
        cap.densify_pruned = rounds.iter().map(|r| r.pruned).sum();
        cap.densify_relocated = rounds.iter().map(|r| r.relocated).sum();
        // Each band is 5 floats; ×3 with the Adam moments.
        cap.band_bytes_saved =
            (cap.bands_initial - m.min(cap.bands_initial)) * 5 * 4 * 3 * self.prims.len();
        cap.gaussian_path_primitives = (0..self.prims.len())
            .filter(|&i| {
                is_beta_frozen(f64::from(self.prims.beta_raw[i])) && self.prims.live_bands(i) == 0
            })
            .count();
        cap.band_holders = (0..self.prims.len())
            .filter(|&i| self.prims.live_bands(i) > 0)
            .count();
        cap.band_slots_dropped = (0..self.prims.len())
            .map(|i| m - self.prims.live_bands(i))
            .sum();
        cap.response = Some(self.response_summary());
        if let Some(a) = cap.align_gradient.as_mut() {
            a.summarise();
        }
        if cap.step_ms_before_compaction.is_some() && self.state.step_count > 0 {
            cap.step_ms_after_compaction =
                Some(self.state.step_ms_sum / self.state.step_count as f64);
        }
        cap
    }

    /// CPU reference forward + backward of the first training view, best of 3, with the
    /// renderer's shortcuts and with every primitive forced through the general path (ms).
    pub(super) fn cpu_shortcut_timing(&self) -> Result<Option<(f64, f64)>, TrainError> {
        use crate::render::{RenderSettings, prepare, render_backward_prepared, render_prepared};
        let Some(&vi) = self.data.train.first() else {
            return Ok(None);
        };
        let cam = self.data.views[vi].camera;
        let prep = prepare(&self.prims, &cam, &RenderSettings::default())?;
        let general = prep.without_shortcuts(self.prims.bands);
        let mut up = GBuffers::<f32>::zeros(prep.width, prep.height, !self.prims.sh.is_empty());
        up.thermal.fill(1.0);
        let time = |p: &crate::render::Prepared<f32>| {
            (0..3)
                .map(|_| {
                    let t0 = Instant::now();
                    let gb = render_prepared(&self.prims, p);
                    let g = render_backward_prepared(&self.prims, p, &up);
                    std::hint::black_box((gb, g));
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .fold(f64::INFINITY, f64::min)
        };
        Ok(Some((time(&prep), time(&general))))
    }
}

/// The iteration (and training seconds) a run became Gaussian-only.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct GaussianFrom {
    pub iteration: u64,
    pub seconds: f64,
}

/// What capacity adaptation left out and what it saved.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CapacityReport {
    pub mode: String,
    pub colour_allocated: bool,
    pub colour_reason: String,
    pub consistency_pairs: usize,
    pub consistency_reason: String,
    pub bands_initial: usize,
    pub bands_now: usize,
    /// Bands dropped at the last check (sum over primitives).
    pub bands_dropped_total: usize,
    /// Dropped band slots still in storage (below M, above a primitive's live count): the
    /// renderer skips them and Adam never updates them.
    #[serde(default)]
    pub band_slots_dropped: usize,
    /// Bytes freed by band compaction (parameters and both Adam moments).
    pub band_bytes_saved: usize,
    /// Primitives on the cheap Gaussian path (β exactly 2 and frozen, no live band).
    pub gaussian_path_primitives: usize,
    /// Primitives snapped to β = 2 and frozen by the last check.
    #[serde(default)]
    pub gaussian_frozen_last_check: usize,
    /// CPU reference renderer, forward + backward of one training view at the end of the run:
    /// with the shortcuts (cheap Gaussian path, dropped slots skipped) and with every primitive
    /// forced through the general path (ms, best of 3); only with `cpu_timing` (else null).
    #[serde(default)]
    pub cpu_step_ms_with_shortcuts: Option<f64>,
    #[serde(default)]
    pub cpu_step_ms_general_path: Option<f64>,
    pub primitives: usize,
    pub memory_bytes: usize,
    /// Mean step time before and after the last band compaction (ms).
    pub step_ms_before_compaction: Option<f64>,
    pub step_ms_after_compaction: Option<f64>,
    /// Every density-control round so far: primitives before and after, cloned, split,
    /// pruned, left out for the budget.
    #[serde(default)]
    pub densify_rounds: Vec<DensifyRound>,
    /// Sums over the rounds (filled by [`Trainer::capacity_report`]).
    #[serde(default)]
    pub densify_cloned: usize,
    #[serde(default)]
    pub densify_split: usize,
    #[serde(default)]
    pub densify_pruned: usize,
    #[serde(default)]
    pub densify_relocated: usize,
    /// The per-view radiometric responses the run learned, and why (filled by
    /// [`Trainer::capacity_report`]).
    #[serde(default)]
    pub response: Option<super::ResponseSummary>,
    /// Joint runs: which loss the RGB views take and why (`None`: no RGB views).
    #[serde(default)]
    pub rgb_loss: Option<String>,
    /// The thermal gradient alignment loss's weight after the RGB pre-training (0: off).
    #[serde(default)]
    pub thermal_align: f64,
    /// How hard the alignment loss pulls on the geometry beside the thermal views' other terms,
    /// sampled during the run (`None`: the loss was never on).
    #[serde(default)]
    pub align_gradient: Option<AlignGradient>,
    /// Primitives holding at least one live band (filled by [`Trainer::capacity_report`]).
    #[serde(default)]
    pub band_holders: usize,
    /// The band grant and every check that dropped bands, in order.
    #[serde(default)]
    pub band_rounds: Vec<BandRound>,
    /// When every primitive reached the Gaussian path (no band, β frozen at 2) in a mode with
    /// bands or learnable β; the spectral terms are off from then on (`None`: never).
    #[serde(default)]
    pub gaussian_from: Option<GaussianFrom>,
    pub notes: Vec<String>,
}

/// The alignment loss's share of the gradient, sampled every
/// [`super::joint::ALIGN_SHARE_EVERY`]-th iteration on thermal views
/// ([`Trainer::measure_align_share`]): `‖∂L_align/∂μ‖ / ‖∂L_rest/∂μ‖` over the primitives'
/// positions, `L_rest` being the view's other terms. Around 0.01 the loss barely moves the
/// geometry; around 1 it pulls as hard as the images do.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AlignGradient {
    /// Every sample, in order.
    pub ratios: Vec<f64>,
    /// Filled by [`Trainer::capacity_report`].
    pub samples: usize,
    pub median: Option<f64>,
    pub p90: Option<f64>,
}

impl AlignGradient {
    /// Fills the summary from the samples: nearest ranks, the upper median as the trainer's
    /// `median` has it.
    fn summarise(&mut self) {
        let mut v = self.ratios.clone();
        v.sort_by(f64::total_cmp);
        self.samples = v.len();
        let at = |q: f64| {
            v.get(((v.len() as f64 - 1.0) * q).round() as usize)
                .copied()
        };
        self.median = at(0.5);
        self.p90 = at(0.9);
    }
}
