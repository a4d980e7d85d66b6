//! Per-view radiometric response learned with the scene (`--response`).
//!
//! Real thermal frames of one scene disagree: 8-bit exports are tone-mapped per frame by the
//! camera's automatic gain control (the same wall has another grey level in every frame), and
//! 16-bit radiometric frames drift between flat-field corrections. Each training view gets its
//! own response ([`ViewResponse`]: `gain·(x − pivot) + pivot + offset` on the rendered
//! thermal plane) learned by Adam with the scene:
//!
//! - [`ResponseKind::Affine`]: gain and offset (8-bit, non-radiometric input);
//! - [`ResponseKind::Offset`]: offset only (16-bit radiometric input: drift is additive);
//! - [`ResponseKind::None`]: no parameters.
//!
//! The gain is learned as its logarithm (positive by construction). **Anchoring**: after
//! every update the training views' offsets and log-gains are shifted to mean zero, so the
//! scene's level and contrast are those of the cameras' mean and the model cannot drift as a
//! whole (a shift of every response and the opposite shift of the scene would otherwise cost
//! nothing). When the dataset says which views were taken right after a flat-field
//! correction (`ffc.txt`, [`crate::dataset::Dataset::fresh_after_ffc`]) and the input is
//! radiometric, the drift resets there: those training views' offsets are pinned at zero and
//! they, not the cameras' mean, fix the scene's absolute temperature (a random walk from zero
//! has a mean of its own, which the cameras' mean would carry into the scene). A weak L2
//! prior (`prior`) keeps each view's parameters small where its image says little. Held-out views have no learned response: they are rendered with the identity
//! (the mean camera) and evaluated raw and affine-aligned ([`crate::metrics`]).
//!
//! `--response auto` (the default) learns the kind that fits the input (affine for 8-bit,
//! offset for 16-bit) and, once [`DECIDE_AT_PROGRESS`] of the run is done and every training
//! view's response has had [`DECIDE_AFTER_UPDATES`] updates, drops it when the views agree
//! (every learned offset within [`AGREE_OFFSET_K`] kelvin — [`AGREE_OFFSET`] for
//! non-radiometric input — and log-gain within [`AGREE_LOG_GAIN`]): a dataset whose frames
//! agree ends without response parameters, and the "left out" line says so. Why this late:
//! until the scene fits, each view's offset also takes up the scene's error in that view
//! (measured on frames that agree: −1.05…+0.21 K on the simulated objects scene after a 60 s
//! run, ±0.03 K on the simulated wall after 1 200 iterations), and Adam's steps are as large
//! as its learning rate whatever the gradient; by mid-run the scene fits better and the
//! learning rate has decayed. A scene that never fits well keeps its offsets, which then
//! only take up its per-view error.

use serde::{Deserialize, Serialize};

use super::adam::{AdamParams, step_size, update};
use super::{Backend, Trainer};
use crate::dataset::ThermalRange;
use crate::dataset::images::ImageKind;
use crate::loss::response::{ResponseGrad, ViewResponse};

/// `--response auto` drops a learned response whose views agree this closely: offsets within
/// this many kelvin on radiometric input (about an uncooled core's NETD)…
pub const AGREE_OFFSET_K: f64 = 0.1;
/// … or this much of the range on other input (half a grey level of an 8-bit image)…
pub const AGREE_OFFSET: f64 = 0.002;
/// … and log-gains within this (0.5 % gain).
pub const AGREE_LOG_GAIN: f64 = 0.005;
/// `auto` decides once this fraction of the run is done…
pub const DECIDE_AT_PROGRESS: f64 = 0.5;
/// … and every training view's response has had this many updates.
pub const DECIDE_AFTER_UPDATES: u64 = 10;

/// Which per-view response is learned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ResponseKind {
    /// Affine for 8-bit input, offset for 16-bit; dropped by mid-run when the views agree.
    #[default]
    Auto,
    None,
    Offset,
    Affine,
}

impl ResponseKind {
    /// The kind `auto` learns for thermal images of `range` (none without thermal images).
    pub fn for_input(self, range: Option<&ThermalRange>) -> ResponseKind {
        match (self, range) {
            (ResponseKind::Auto, None) => ResponseKind::None,
            (ResponseKind::Auto, Some(r)) => match r.kind {
                ImageKind::Thermal16 => ResponseKind::Offset,
                _ => ResponseKind::Affine,
            },
            (k, _) => k,
        }
    }
}

impl std::fmt::Display for ResponseKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ResponseKind::Auto => "auto",
            ResponseKind::None => "none",
            ResponseKind::Offset => "offset",
            ResponseKind::Affine => "affine",
        })
    }
}

impl std::str::FromStr for ResponseKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(ResponseKind::Auto),
            "none" => Ok(ResponseKind::None),
            "offset" => Ok(ResponseKind::Offset),
            "affine" => Ok(ResponseKind::Affine),
            other => Err(format!(
                "unknown response `{other}` (expected auto, none, offset or affine)"
            )),
        }
    }
}

/// Settings of the per-view response (`config.json`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ResponseConfig {
    pub kind: ResponseKind,
    /// Adam learning rate of the offsets (normalised units) at the start; decays
    /// exponentially to `lr_final_ratio` × itself over the run.
    pub lr_offset: f64,
    /// Adam learning rate of the log-gains at the start (decays the same way).
    pub lr_log_gain: f64,
    pub lr_final_ratio: f64,
    /// Weight of the L2 prior `prior·(offset² + log_gain²)` on each view's parameters.
    pub prior: f64,
}

impl Default for ResponseConfig {
    fn default() -> Self {
        Self {
            kind: ResponseKind::Auto,
            // Measured on the simulated wall with drift (64×48, 1 200 iterations): 5e-3 left
            // the held-out bias at +0.09 K, 1e-2 at +0.02 K (MAE 0.117 → 0.094 K).
            lr_offset: 1e-2,
            lr_log_gain: 2e-2,
            lr_final_ratio: 0.1,
            prior: 0.01,
        }
    }
}

/// The learned responses of a run (kept in its checkpoint).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResponseModel {
    /// What is learned ([`ResponseKind::Affine`] or [`ResponseKind::Offset`]).
    pub kind: ResponseKind,
    /// Whether `auto` chose it (and may drop it when the views agree).
    pub automatic: bool,
    /// The gain's pivot: the training images' mean level (normalised).
    pub pivot: f64,
    /// Per view of the dataset (held-out views stay at zero: the identity).
    pub log_gain: Vec<f64>,
    pub offset: Vec<f64>,
    /// Adam moments (log-gain, offset) and update counts, per view.
    m: Vec<[f64; 2]>,
    v: Vec<[f64; 2]>,
    steps: Vec<u64>,
    /// The views the anchoring averages over (the training views).
    train: Vec<usize>,
    /// `auto` has decided whether to keep it ([`Trainer::decide_response`]).
    #[serde(default)]
    decided: bool,
    /// Training views whose offsets are pinned at zero (taken right after a flat-field
    /// correction); empty: the offsets are anchored at their mean.
    #[serde(default)]
    pub pinned: Vec<usize>,
}

/// What [`ResponseModel::summary`] reports (`capacity.json`, the log).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ResponseSummary {
    /// `none`, `offset` or `affine` (what the run ended with).
    pub kind: String,
    /// Why (the "left out" line).
    pub reason: String,
    /// `auto` dropped it by mid-run because the views agreed.
    #[serde(default)]
    pub dropped_as_agreeing: bool,
    /// Per training view: name, gain, offset (normalised units) and, when radiometric, the
    /// offset in kelvin.
    pub views: Vec<ViewResponseRecord>,
}

impl ResponseSummary {
    /// One line for the log: kind, reason, and the ranges of the learned gains and offsets
    /// (kelvin too when radiometric).
    pub fn describe(&self) -> String {
        let range = |v: &mut dyn Iterator<Item = f64>| {
            v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            })
        };
        if self.views.is_empty() {
            return format!("{} ({})", self.kind, self.reason);
        }
        let (g0, g1) = range(&mut self.views.iter().map(|v| v.gain));
        let (b0, b1) = range(&mut self.views.iter().map(|v| v.offset));
        let kelvin = match range(&mut self.views.iter().filter_map(|v| v.offset_kelvin)) {
            (k0, k1) if k0 <= k1 => format!(" ({k0:+.2}…{k1:+.2} K)"),
            _ => String::new(),
        };
        format!(
            "{} ({}): gains {g0:.3}…{g1:.3}, offsets {b0:+.4}…{b1:+.4}{kelvin}",
            self.kind, self.reason
        )
    }
}

/// One view's learned response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewResponseRecord {
    pub name: String,
    pub gain: f64,
    pub offset: f64,
    pub offset_kelvin: Option<f64>,
}

/// Adam's hyper-parameters for the responses (3DGS's β's; ε above the gradients' f64 noise).
const ADAM: AdamParams = AdamParams {
    beta1: 0.9,
    beta2: 0.999,
    eps: 1e-12,
    band_l1: 0.0,
};

impl ResponseModel {
    /// Identity responses for `views` views, anchored over `train` (offsets pinned at zero on
    /// `pinned` instead, when not empty); `None` for [`ResponseKind::None`] (nothing
    /// allocated).
    pub fn new(
        kind: ResponseKind,
        automatic: bool,
        pivot: f64,
        views: usize,
        train: Vec<usize>,
        pinned: Vec<usize>,
    ) -> Option<Self> {
        matches!(kind, ResponseKind::Offset | ResponseKind::Affine).then(|| Self {
            kind,
            automatic,
            pivot,
            log_gain: vec![0.0; views],
            offset: vec![0.0; views],
            m: vec![[0.0; 2]; views],
            v: vec![[0.0; 2]; views],
            steps: vec![0; views],
            train,
            decided: !automatic,
            pinned,
        })
    }

    /// View `vi`'s current response.
    pub fn of_view(&self, vi: usize) -> ViewResponse {
        ViewResponse {
            gain: self.log_gain.get(vi).map_or(1.0, |a| a.exp()),
            offset: self.offset.get(vi).copied().unwrap_or(0.0),
            pivot: self.pivot,
        }
    }

    /// One Adam step of view `vi`'s response from its loss gradient, with learning rates
    /// scaled by `decay` (1 at the start of the run), then the anchoring.
    pub fn step(&mut self, cfg: &ResponseConfig, vi: usize, grad: ResponseGrad, decay: f64) {
        if vi >= self.offset.len() || !grad.gain.is_finite() || !grad.offset.is_finite() {
            return;
        }
        let gain = self.log_gain[vi].exp();
        // dL/d(log g) = g·dL/dg; the prior adds 2·prior·value.
        let g = [
            gain * grad.gain + 2.0 * cfg.prior * self.log_gain[vi],
            grad.offset + 2.0 * cfg.prior * self.offset[vi],
        ];
        let lrs = [cfg.lr_log_gain * decay, cfg.lr_offset * decay];
        let learns = [
            self.kind == ResponseKind::Affine,
            !self.pinned.contains(&vi),
        ];
        self.steps[vi] += 1;
        let t = self.steps[vi];
        for k in 0..2 {
            if !learns[k] {
                continue;
            }
            let size = step_size(lrs[k], t, &ADAM);
            let (m, v) = (&mut self.m[vi][k], &mut self.v[vi][k]);
            let delta = update(m, v, g[k], size, ADAM.as_f64());
            if k == 0 {
                self.log_gain[vi] -= delta;
            } else {
                self.offset[vi] -= delta;
            }
        }
        self.anchor();
    }

    /// Shifts the training views' log-gains to mean zero, and their offsets too unless some
    /// are pinned at zero (which then fix the level).
    fn anchor(&mut self) {
        let n = self.train.len();
        if n == 0 {
            return;
        }
        let mean_a = self.train.iter().map(|&i| self.log_gain[i]).sum::<f64>() / n as f64;
        let mean_b = if self.pinned.is_empty() {
            self.train.iter().map(|&i| self.offset[i]).sum::<f64>() / n as f64
        } else {
            0.0
        };
        for &i in &self.train {
            self.log_gain[i] -= mean_a;
            self.offset[i] -= mean_b;
        }
        for &i in &self.pinned {
            self.offset[i] = 0.0;
        }
    }

    /// Whether every training view has had `n` updates.
    fn each_view_updated(&self, n: u64) -> bool {
        self.train.iter().all(|&i| self.steps[i] >= n)
    }

    /// Whether every training view's response is within the agreement tolerances of the
    /// identity: offsets within `offset_tolerance` (normalised units), log-gains within
    /// [`AGREE_LOG_GAIN`].
    pub fn views_agree(&self, offset_tolerance: f64) -> bool {
        self.train.iter().all(|&i| {
            self.offset[i].abs() <= offset_tolerance && self.log_gain[i].abs() <= AGREE_LOG_GAIN
        })
    }

    /// Per-training-view figures for the reports.
    pub fn summary(&self, names: &[String], range: Option<&ThermalRange>) -> ResponseSummary {
        let k = range.and_then(ThermalRange::kelvin_per_unit);
        ResponseSummary {
            kind: self.kind.to_string(),
            reason: String::new(),
            dropped_as_agreeing: false,
            views: self
                .train
                .iter()
                .map(|&i| ViewResponseRecord {
                    name: names.get(i).cloned().unwrap_or_default(),
                    gain: self.log_gain[i].exp(),
                    offset: self.offset[i],
                    offset_kelvin: k.map(|k| self.offset[i] * k),
                })
                .collect(),
        }
    }
}

impl<B: Backend> Trainer<B> {
    /// The response a new run learns: the configured kind (`auto`: by input), identity for
    /// every view, pivot at the training images' mean level.
    pub(super) fn initial_response(&self) -> Option<ResponseModel> {
        let c = self.cfg.response;
        let kind = c.kind.for_input(self.data.range.as_ref());
        let (mut sum, mut n) = (0.0, 0usize);
        for &i in &self.data.train {
            if let Some(t) = &self.data.views[i].thermal {
                sum += t.iter().map(|&v| f64::from(v)).sum::<f64>();
                n += t.len();
            }
        }
        let pivot = if n > 0 { sum / n as f64 } else { 0.5 };
        let train: Vec<usize> = self
            .data
            .train
            .iter()
            .copied()
            .filter(|&i| self.data.views[i].thermal.is_some())
            .collect();
        let radiometric = self
            .data
            .range
            .is_some_and(|r| r.kind == ImageKind::Thermal16);
        let pinned: Vec<usize> = match (&self.data.fresh_after_ffc, radiometric) {
            (Some(fresh), true) => fresh
                .iter()
                .copied()
                .filter(|i| train.contains(i))
                .collect(),
            _ => Vec::new(),
        };
        ResponseModel::new(
            kind,
            c.kind == ResponseKind::Auto,
            pivot,
            self.data.views.len(),
            train,
            pinned,
        )
    }

    /// Once [`DECIDE_AT_PROGRESS`] of the run is done and every training view's response has
    /// had [`DECIDE_AFTER_UPDATES`] updates, `auto` decides: a response whose views agree is
    /// dropped (the run continues without response parameters), otherwise it stays.
    pub(super) fn decide_response(&mut self) {
        let progress = self.progress();
        let Some(m) = &mut self.state.response else {
            return;
        };
        if m.decided || progress < DECIDE_AT_PROGRESS || !m.each_view_updated(DECIDE_AFTER_UPDATES)
        {
            return;
        }
        m.decided = true;
        let tolerance = self
            .data
            .range
            .as_ref()
            .and_then(ThermalRange::kelvin_per_unit)
            .map_or(AGREE_OFFSET, |k| AGREE_OFFSET_K / k);
        if m.views_agree(tolerance) {
            tracing::info!(
                kind = %m.kind,
                "the views' learned responses agree: response dropped"
            );
            self.state.response = None;
            self.state.response_dropped = true;
        } else {
            tracing::info!(kind = %m.kind, "the views' responses differ: response kept");
        }
    }

    /// What the run learns for the views' responses, and why.
    pub fn response_summary(&self) -> ResponseSummary {
        let names: Vec<String> = self.data.views.iter().map(|v| v.name.clone()).collect();
        let input = match self.data.range.as_ref().map(|r| r.kind) {
            Some(ImageKind::Thermal16) => "16-bit radiometric input",
            Some(_) => "8-bit input",
            None => "no thermal views",
        };
        match &self.state.response {
            Some(m) => {
                let mut s = m.summary(&names, self.data.range.as_ref());
                s.reason = if m.automatic {
                    format!("auto: {} per view for {input}", m.kind)
                } else {
                    format!("--response {}", m.kind)
                };
                s.reason += &if m.pinned.is_empty() {
                    "; anchored at the cameras' mean".to_owned()
                } else {
                    format!(
                        "; offsets pinned at zero on {} training views taken right after a \
                         flat-field correction (ffc.txt)",
                        m.pinned.len()
                    )
                };
                s
            }
            None => ResponseSummary {
                kind: ResponseKind::None.to_string(),
                reason: if self.state.response_dropped {
                    "auto: the views' learned responses agreed by mid-run (offsets within 0.1 K \
                     or half a grey level, gains within 0.5 %): dropped"
                        .to_owned()
                } else if self.cfg.response.kind == ResponseKind::None {
                    "--response none".to_owned()
                } else {
                    format!("not needed: {input}")
                },
                dropped_as_agreeing: self.state.response_dropped,
                views: Vec::new(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    /// Adam on a quadratic loss per view finds each view's optimum, and the anchoring keeps
    /// the means at zero. The optima have zero mean, as in training, where the scene takes up
    /// any common part (Adam's normalised steps would not settle a common pull the anchoring
    /// keeps undoing).
    #[test]
    fn steps_converge_to_anchored_optimum() {
        let cfg = ResponseConfig {
            prior: 0.0,
            ..ResponseConfig::default()
        };
        let mut m = ResponseModel::new(
            ResponseKind::Affine,
            false,
            0.5,
            4,
            vec![0, 1, 2],
            Vec::new(),
        )
        .expect("affine allocates");
        // Per-view optima (log-gain, offset); view 3 is held out.
        let want = [(0.2, 0.05), (-0.15, -0.02), (-0.05, -0.03)];
        for it in 0..6000 {
            let vi = it % 3;
            let r = m.of_view(vi);
            let (a, b) = want[vi];
            // L = (log g − a)² + (b' − b)² → dL/dg = 2(log g − a)/g.
            let grad = ResponseGrad {
                gain: 2.0 * (r.gain.ln() - a) / r.gain,
                offset: 2.0 * (r.offset - b),
            };
            m.step(&cfg, vi, grad, 0.2);
        }
        let (ma, mb) = (
            want.iter().map(|w| w.0).sum::<f64>() / 3.0,
            want.iter().map(|w| w.1).sum::<f64>() / 3.0,
        );
        for (vi, (a, b)) in want.iter().enumerate() {
            assert!(
                (m.log_gain[vi] - (a - ma)).abs() < 5e-3,
                "view {vi}: log-gain {} expected {}",
                m.log_gain[vi],
                a - ma
            );
            assert!(
                (m.offset[vi] - (b - mb)).abs() < 5e-3,
                "view {vi}: offset {} expected {}",
                m.offset[vi],
                b - mb
            );
        }
        assert_eq!(
            m.of_view(3),
            ViewResponse::identity(0.5),
            "held-out view stays identity"
        );
        let s: f64 = (0..3).map(|i| m.offset[i]).sum();
        assert!(s.abs() < 1e-12, "anchored offsets sum to {s}, expected 0");
    }

    /// Views pinned after a flat-field correction keep offset zero; the others are not
    /// re-centred (the pinned views fix the level).
    #[test]
    fn pinned_views_fix_the_offsets_level() {
        let mut m = ResponseModel::new(ResponseKind::Offset, false, 0.5, 3, vec![0, 1, 2], vec![1])
            .expect("offset allocates");
        let cfg = ResponseConfig {
            prior: 0.0,
            ..ResponseConfig::default()
        };
        let want = [0.03, 0.0, 0.05];
        for it in 0..3000 {
            let vi = it % 3;
            let grad = ResponseGrad {
                gain: 0.0,
                offset: 2.0 * (m.offset[vi] - want[vi]),
            };
            m.step(&cfg, vi, grad, 0.2);
        }
        assert_eq!(m.offset[1], 0.0, "pinned view moved");
        for vi in [0, 2] {
            assert!(
                (m.offset[vi] - want[vi]).abs() < 3e-3,
                "view {vi}: offset {} expected {} (no re-centring with pinned views)",
                m.offset[vi],
                want[vi]
            );
        }
    }

    #[test]
    fn offset_kind_never_moves_the_gain() {
        let mut m = ResponseModel::new(ResponseKind::Offset, false, 0.5, 2, vec![0, 1], Vec::new())
            .expect("offset allocates");
        let grad = ResponseGrad {
            gain: 1.0,
            offset: 1.0,
        };
        m.step(&ResponseConfig::default(), 0, grad, 1.0);
        assert_eq!(m.log_gain, vec![0.0, 0.0], "offset kind learned a gain");
        assert!(m.offset[0] < 0.0 && m.offset[1] > 0.0, "{:?}", m.offset);
        assert!(
            ResponseModel::new(ResponseKind::None, false, 0.5, 2, vec![0, 1], Vec::new()).is_none()
        );
    }
}
