//! Adam (Kingma & Ba) per parameter group, moments stored in the primitives' own layout.
//!
//! The β group is optimised **in β units**, not in the renderer's `beta_raw` units: the
//! parameterisation `β = 2 + softplus(beta_raw)` starts at `beta_raw = −10` where
//! `dβ/dbeta_raw = 4.5e-5`, so a learning rate of 0.001 on `beta_raw` would take ~10⁴ steps to
//! move β by one. The paper's "β lr 0.001" is read as a step size on β itself: the gradient is
//! mapped `g_β = g_raw / (dβ/dbeta_raw)`, Adam steps β, β is clamped to [2, 64] and mapped back
//! with [`beta_raw_from_beta`].
//!
//! Two kinds of values are never updated (their moments are held at 0): a `beta_raw` frozen on the
//! Gaussian path ([`is_beta_frozen`]), and every parameter of a dropped band slot (slot `j ≥
//! band_count[i]`), so dropped bands cannot grow back whatever gradient a backend reports for
//! them.

use serde::{Deserialize, Serialize};

use crate::primitive::{BETA_MAX, Primitives, beta_of_raw, beta_raw_from_beta, is_beta_frozen};

/// Adam hyper-parameters shared by every group.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AdamParams {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl Default for AdamParams {
    fn default() -> Self {
        // 3DGS's values.
        Self {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

/// Learning rate of every group (0: frozen).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GroupLrs {
    pub means: f64,
    pub log_scales: f64,
    pub quats: f64,
    pub opacity_logits: f64,
    /// In β units (see the module docs).
    pub beta: f64,
    pub omega_low: f64,
    pub band_amp: f64,
    pub band_freq: f64,
    pub band_phase: f64,
    pub sh: f64,
}

impl GroupLrs {
    fn of(&self, group: &str) -> f64 {
        match group {
            "means" => self.means,
            "log_scales" => self.log_scales,
            "quats" => self.quats,
            "opacity_logits" => self.opacity_logits,
            "beta_raw" => self.beta,
            "omega_low" => self.omega_low,
            "band_amp" => self.band_amp,
            "band_freq" => self.band_freq,
            "band_phase" => self.band_phase,
            _ => self.sh,
        }
    }
}

/// Moments and the step count.
#[derive(Debug, Clone, PartialEq)]
pub struct AdamState {
    pub m: Primitives<f32>,
    pub v: Primitives<f32>,
    pub step: u64,
}

impl AdamState {
    pub fn new(like: &Primitives<f32>) -> Self {
        Self {
            m: like.zeros_like(),
            v: like.zeros_like(),
            step: 0,
        }
    }

    /// One Adam step of `params` along `grads` (same layout). Non-finite gradients count as 0.
    pub fn step(
        &mut self,
        params: &mut Primitives<f32>,
        grads: &Primitives<f32>,
        lrs: &GroupLrs,
        hp: &AdamParams,
    ) {
        self.step += 1;
        let t = self.step as f64;
        let bc1 = 1.0 - hp.beta1.powf(t);
        let bc2 = 1.0 - hp.beta2.powf(t);
        let (b1, b2) = (hp.beta1 as f32, hp.beta2 as f32);
        let bands = params.bands;
        let live: Vec<usize> = (0..params.len()).map(|i| params.live_bands(i)).collect();
        let groups = params
            .groups_mut()
            .into_iter()
            .zip(grads.groups())
            .zip(self.m.groups_mut().into_iter().zip(self.v.groups_mut()));
        for (((name, p), (_, g)), ((_, m), (_, v))) in groups {
            let lr = lrs.of(name);
            if lr == 0.0 {
                continue;
            }
            let step = (lr / bc1) as f32;
            let bc2s = bc2.sqrt() as f32;
            let eps = hp.eps as f32;
            // Values per band slot in a band group (0: not a band group).
            let per_slot = match name {
                "band_amp" | "band_phase" => 1,
                "band_freq" => 3,
                _ => 0,
            };
            for i in 0..p.len() {
                let held = match i.checked_div(per_slot) {
                    Some(slot) => slot % bands >= live[slot / bands],
                    None => name == "beta_raw" && is_beta_frozen(f64::from(p[i])),
                };
                if held {
                    m[i] = 0.0;
                    v[i] = 0.0;
                    continue;
                }
                let mut gi = if g[i].is_finite() { g[i] } else { 0.0 };
                if name == "beta_raw" {
                    let (_, dbeta) = beta_of_raw(f64::from(p[i]));
                    gi = if dbeta > 0.0 {
                        (f64::from(gi) / dbeta) as f32
                    } else {
                        0.0
                    };
                    if !gi.is_finite() {
                        gi = 0.0;
                    }
                }
                m[i] = b1 * m[i] + (1.0 - b1) * gi;
                v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                let delta = step * m[i] / (v[i].sqrt() / bc2s + eps);
                if name == "beta_raw" {
                    let beta = beta_of_raw(f64::from(p[i])).0 - f64::from(delta);
                    p[i] = beta_raw_from_beta(beta.clamp(2.0, BETA_MAX)) as f32;
                } else {
                    p[i] -= delta;
                }
            }
        }
    }
}
