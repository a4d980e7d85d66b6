//! Joint RGB + thermal training on shared geometry (TGA-GS, paper §3.3–3.4): which views a step
//! may draw (RGB pre-training), the modality weights, the RGB views' loss (L1-low when they are
//! dark) and the thermal gradient alignment term on thermal views.
//!
//! A dataset with both image sets (e.g. `s3tir-firmware-sim scene --rgb-scale K`, or a COLMAP
//! model holding a rig's RGB and thermal images with their own cameras) trains one set of
//! primitives: each has its S³-TIR thermal radiance and an SH colour; every view supervises
//! its own head through its own camera. Nothing here acts in a run without RGB views, except
//! an explicitly set `--thermal-align`.
//!
//! Where this differs from the paper: the paper's SR networks (a learned thermal and RGB
//! super-resolution stage after the splatting, with a VGG perceptual loss) are not built — no
//! network weights can be fetched here; super-resolved thermal comes from rendering the shared
//! geometry at a higher resolution (`crate::truth` scores it against bicubic upsampling).

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::adam::{AdamParams, step_size, update};
use super::config::{DEFAULT_THERMAL_ALIGN, LOW_LIGHT_MEAN, RgbLoss};
use super::{Backend, TrainError, Trainer};
use crate::dataset::Dataset;
use crate::loss::LossWeights;
use crate::loss::align::{AlignSettings, thermal_align};
use crate::loss::photometric::{l1_dssim, l1_low_dssim};
use crate::primitive::Primitives;
use crate::real::Real;
use crate::render::GBuffers;

/// Every this-many iterations a thermal host step with the alignment loss on measures the
/// loss's share of the position gradient ([`Trainer::measure_align_share`]: one more backward
/// pass, ~1 % of a joint run's steps).
pub const ALIGN_SHARE_EVERY: u64 = 25;

/// Each training view's partner of the other modality: the nearest camera of the other
/// modality among the training views whose images overlap it (≥ half of a 6×6 ray grid cut at
/// the scene centre) — on a rig, the other camera's image of the same instant (a few
/// centimetres away; a neighbouring instant may overlap as much, but is further).
pub(super) fn modality_partners(data: &Dataset, centre: [f64; 3]) -> Vec<Option<usize>> {
    let mut out = vec![None; data.views.len()];
    if !(data.has_rgb() && data.has_thermal()) {
        return out;
    }
    for &i in &data.train {
        let a = &data.views[i];
        let ca = a.camera.centre_world();
        let mut best: Option<(f64, usize)> = None;
        for &j in &data.train {
            let b = &data.views[j];
            if b.thermal.is_some() == a.thermal.is_some() {
                continue;
            }
            let o = super::init::view_overlap(&a.camera, &b.camera, centre);
            if o < 0.5 {
                continue;
            }
            let cb = b.camera.centre_world();
            let d = (0..3).map(|k| (ca[k] - cb[k]).powi(2)).sum::<f64>();
            if best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, j));
            }
        }
        out[i] = best.map(|b| b.1);
    }
    out
}

/// Mean value of the RGB training views (sRGB-encoded, [0, 1]); `None` without RGB views.
pub(super) fn rgb_mean(data: &Dataset) -> Option<f64> {
    let (sum, n) = data
        .train
        .iter()
        .filter_map(|&i| data.views[i].rgb.as_ref())
        .fold((0.0, 0usize), |(s, n), v| {
            (
                s + v.iter().map(|&x| f64::from(x)).sum::<f64>(),
                n + v.len(),
            )
        });
    (n > 0).then(|| sum / n as f64)
}

impl<B: Backend> Trainer<B> {
    /// The view of the other modality that trains with view `vi` in this step (see
    /// [`super::Joint::pair_steps`]; `None` during the RGB pre-training).
    pub(super) fn modality_partner(&self, vi: usize) -> Option<usize> {
        if !self.cfg.joint.pair_steps || self.in_rgb_pretrain() {
            return None;
        }
        self.modality_partners.get(vi).copied().flatten()
    }

    /// Renders the partner view `vr`, takes its own terms and back-propagates them: its loss
    /// and gradients (the RGB background steps here when `vr` is an RGB view).
    pub(super) fn partner_gradients(
        &mut self,
        vr: usize,
        weights: &LossWeights,
    ) -> Result<(f64, Primitives<f32>), TrainError> {
        let cam = self.data.views[vr].camera;
        let gb = self.backend.render(&self.prims, &cam)?;
        let mut up = GBuffers::zeros(gb.width, gb.height, !self.prims.sh.is_empty());
        let terms = self.view_terms(vr, &gb, weights, &mut up)?;
        if let (Some(bg), Some(g)) = (self.state.background.as_mut(), terms.background) {
            bg.step(g);
        }
        let decay = self.cfg.response.lr_final_ratio.powf(self.progress());
        if let (Some(model), Some(g)) = (self.state.response.as_mut(), terms.response) {
            model.step(&self.cfg.response, vr, g, decay);
        }
        let loss = terms.loss;
        let g = self.backend.backward(&self.prims, &cam, &up)?;
        Ok((loss, g))
    }

    /// The RGB pre-training is on: only RGB views train.
    pub(super) fn in_rgb_pretrain(&self) -> bool {
        self.cfg.joint.rgb_pretrain > 0
            && !self.rgb_train.is_empty()
            && self.schedule_iteration() < self.cfg.joint.rgb_pretrain
    }

    /// The training view of a step, drawn from `rng`: an RGB view during the RGB pre-training,
    /// else any training view (the same draw as a run without joint training).
    pub(super) fn draw_view(&self, rng: &mut ChaCha8Rng) -> usize {
        if self.in_rgb_pretrain() {
            self.rgb_train[rng.random_range(0..self.rgb_train.len())]
        } else {
            self.data.train[rng.random_range(0..self.data.train.len())]
        }
    }

    /// The weight of the thermal gradient alignment loss now (0 during the RGB pre-training,
    /// when no thermal view trains; see [`super::Joint::thermal_align`]).
    pub fn thermal_align_weight(&self) -> f64 {
        if self.in_rgb_pretrain() {
            0.0
        } else {
            self.thermal_align_setting()
        }
    }

    /// The alignment loss's weight outside the RGB pre-training: the set one, else
    /// [`DEFAULT_THERMAL_ALIGN`] in a run with both modalities, else 0.
    pub fn thermal_align_setting(&self) -> f64 {
        match self.cfg.joint.thermal_align {
            Some(w) => w,
            None if self.data.has_rgb() && self.data.has_thermal() => DEFAULT_THERMAL_ALIGN,
            None => 0.0,
        }
    }

    /// This host step on view `vi` samples the alignment loss's share of the gradient: a
    /// thermal view while the loss is on, every [`ALIGN_SHARE_EVERY`]-th iteration.
    pub(super) fn align_share_due(&self, vi: usize) -> bool {
        self.data.views[vi].thermal.is_some()
            && self.thermal_align_weight() > 0.0
            && self.iteration.is_multiple_of(ALIGN_SHARE_EVERY)
    }

    /// Measures how hard the alignment loss pulls on the geometry beside the thermal view's
    /// other terms: its own upstream (`gb_i`'s depth and alpha, as the step's loss has it,
    /// modality weight included) through one more backward pass, and the ratio of the position
    /// gradients' norms `‖∂L_align/∂μ‖ / ‖∂L_rest/∂μ‖`, where `L_rest` is every other term of
    /// the view's loss in `g_i` (the step's whole gradient of view `vi`: photometric, SSIM,
    /// regularisers, consistency). Kept in [`super::CapacityReport::align_gradient`].
    pub(super) fn measure_align_share(
        &mut self,
        vi: usize,
        gb_i: &GBuffers<f32>,
        g_i: &Primitives<f32>,
    ) -> Result<(), TrainError> {
        let view = &self.data.views[vi];
        let Some(target) = &view.thermal else {
            return Ok(());
        };
        let w = self.thermal_align_weight() * self.cfg.joint.thermal_weight;
        let mut up = GBuffers::zeros(gb_i.width, gb_i.height, !gb_i.rgb.is_empty());
        thermal_align(
            gb_i,
            target,
            &view.camera,
            &AlignSettings::default(),
            w,
            &mut up,
        )?;
        let g_a = self.backend.backward(&self.prims, &view.camera, &up)?;
        let (mut align, mut rest) = (0.0f64, 0.0f64);
        for (a, all) in g_a.means.iter().zip(&g_i.means) {
            align += f64::from(*a).powi(2);
            rest += f64::from(all - a).powi(2);
        }
        if rest > 0.0 {
            self.state
                .capacity
                .align_gradient
                .get_or_insert_with(Default::default)
                .ratios
                .push((align / rest).sqrt());
        }
        Ok(())
    }

    /// The thermal views' loss has a term only the host computes (the alignment loss): thermal
    /// steps take the host path.
    pub(super) fn host_losses_only(&self) -> bool {
        self.thermal_align_weight() > 0.0
    }

    /// The factor of the super-resolved thermal renders ([`super::Joint::sr_scale`]; `None`:
    /// none).
    pub fn sr_scale(&self) -> Option<usize> {
        let k = match self.cfg.joint.sr_scale {
            Some(k) => k,
            None => {
                let widest = |rgb: bool| {
                    (self.data.views.iter())
                        .filter(|v| v.rgb.is_some() == rgb && (rgb || v.thermal.is_some()))
                        .map(|v| v.camera.width)
                        .max()
                };
                match (widest(true), widest(false)) {
                    (Some(r), Some(t)) if t > 0 => (r as f64 / t as f64).round() as usize,
                    _ => 1,
                }
            }
        };
        (k > 1).then_some(k)
    }

    /// Whether the RGB views' loss is L1-low, and why (for the report).
    pub fn rgb_loss_choice(&self) -> Option<(bool, String)> {
        let mean = self.rgb_mean?;
        Some(match self.cfg.joint.rgb_loss {
            RgbLoss::L1Low => (true, "L1-low (--rgb-loss l1-low)".into()),
            RgbLoss::L1 => (false, "L1 + D-SSIM (--rgb-loss l1): no L1-low".into()),
            RgbLoss::Auto if mean < LOW_LIGHT_MEAN => (
                true,
                format!("L1-low: the RGB views are low-light (mean {mean:.3} < {LOW_LIGHT_MEAN})"),
            ),
            RgbLoss::Auto => (
                false,
                format!(
                    "L1 + D-SSIM: the RGB views are not low-light (mean {mean:.3} ≥ \
                     {LOW_LIGHT_MEAN}): no L1-low"
                ),
            ),
        })
    }

    /// The RGB background colour the run has learned (black without one).
    pub fn rgb_background(&self) -> [f32; 3] {
        self.state
            .background
            .as_ref()
            .map_or([0.0; 3], |b| b.colour.map(|c| c as f32))
    }

    /// The photometric loss of an RGB view (three planes, each a third), weighted by
    /// `joint.rgb_weight`, on the render composited over the learned background
    /// ([`composite_background`]); adds its gradient into `up.rgb` and `up.alpha`, and returns
    /// the gradient of the background colour.
    pub(super) fn rgb_terms(
        &self,
        gb: &GBuffers<f32>,
        target: &[f32],
        weights: &LossWeights,
        up: &mut GBuffers<f32>,
    ) -> Result<(f64, [f64; 3]), TrainError> {
        let n = gb.width * gb.height;
        let low = self.rgb_loss_choice().is_some_and(|(low, _)| low);
        let w = self.cfg.joint.rgb_weight;
        let scale = (w / 3.0) as f32;
        let bg = self.rgb_background();
        let shown = composite_background(&gb.rgb, &gb.alpha, bg);
        let mut g_shown = vec![0.0f32; 3 * n];
        let mut loss = 0.0;
        for c in 0..3 {
            let (img, tgt) = (&shown[c * n..(c + 1) * n], &target[c * n..(c + 1) * n]);
            let grad = &mut g_shown[c * n..(c + 1) * n];
            let r = if low {
                l1_low_dssim(
                    img,
                    tgt,
                    gb.width,
                    gb.height,
                    weights.lambda_dssim,
                    self.cfg.joint.l1_low_eps,
                    scale,
                    grad,
                )?
            } else {
                l1_dssim(
                    img,
                    tgt,
                    gb.width,
                    gb.height,
                    weights.lambda_dssim,
                    scale,
                    grad,
                )?
            };
            loss += w * r.loss / 3.0;
        }
        let g_bg =
            composite_background_backward(&g_shown, &gb.alpha, bg, &mut up.rgb, &mut up.alpha);
        Ok((loss, g_bg))
    }
}

/// The RGB planes as seen over the background colour `bg`: `rgb + (1 − alpha)·bg` per plane
/// (`alpha` is the accumulated opacity, `1 −` the light that passes every primitive).
pub fn composite_background<T: Real>(rgb: &[T], alpha: &[T], bg: [T; 3]) -> Vec<T> {
    let n = alpha.len();
    let mut out = rgb.to_vec();
    for (c, b) in bg.iter().enumerate() {
        for (o, a) in out[c * n..(c + 1) * n].iter_mut().zip(alpha) {
            *o += (T::ONE - *a) * *b;
        }
    }
    out
}

/// The backward pass of [`composite_background`]: given `dL/dshown`, adds `dL/drgb` (= it)
/// into `up_rgb` and `dL/dalpha = −Σ_c bg_c·dL/dshown_c` into `up_alpha`, and returns
/// `dL/dbg_c = Σ_p (1 − alpha_p)·dL/dshown_{c,p}`.
pub fn composite_background_backward<T: Real>(
    g_shown: &[T],
    alpha: &[T],
    bg: [T; 3],
    up_rgb: &mut [T],
    up_alpha: &mut [T],
) -> [f64; 3] {
    let n = alpha.len();
    let mut g_bg = [0.0f64; 3];
    for (c, gb_c) in g_bg.iter_mut().enumerate() {
        for p in 0..n {
            let g = g_shown[c * n + p];
            up_rgb[c * n + p] += g;
            up_alpha[p] -= bg[c] * g;
            *gb_c += ((T::ONE - alpha[p]) * g).to_f64();
        }
    }
    g_bg
}

/// The RGB views' background colour, learned with the scene by Adam on the host: without it
/// a scene's RGB background (sky, far walls) can only be drawn by primitives, which then float
/// in front of the surfaces in the other views and in the thermal head (measured on the
/// simulated joint scene: expected depth 0.16–0.26 m too near; the thermal images see a cold
/// background as "nothing" and need no colour). Starts black; the renderer's alpha G-buffer
/// carries the compositing's gradient back into the primitives.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Background {
    /// Linear in the images' units ([0, 1] per channel), clamped to [0, 1].
    pub colour: [f64; 3],
    m: [f64; 3],
    v: [f64; 3],
    steps: u64,
}

/// Adam learning rate of the background colour (units per step).
pub const BACKGROUND_LR: f64 = 0.01;

impl Background {
    /// A fixed colour (a finished run's, for evaluation).
    pub fn fixed(colour: [f64; 3]) -> Self {
        Self {
            colour,
            ..Self::default()
        }
    }

    /// One Adam step on the background colour's gradient `g`.
    pub fn step(&mut self, g: [f64; 3]) {
        let hp = AdamParams::default();
        self.steps += 1;
        let size = step_size(BACKGROUND_LR, self.steps, &hp);
        let moments = self.m.iter_mut().zip(self.v.iter_mut());
        for ((colour, (m, v)), g) in self.colour.iter_mut().zip(moments).zip(g) {
            if !g.is_finite() {
                continue;
            }
            *colour = (*colour - update(m, v, g, size, hp.as_f64())).clamp(0.0, 1.0);
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::modality_partners;
    use crate::camera::PinholeCamera;
    use crate::dataset::{Dataset, View};

    /// A rig on an orbit, its RGB camera 3 cm beside the thermal one, and an extra RGB view
    /// looking at the scene from a neighbouring spot: every view's partner is the other
    /// camera's image of its own instant, never a neighbouring instant that overlaps as much.
    #[test]
    fn the_partner_is_the_other_camera_of_the_same_instant() {
        let mut views = Vec::new();
        for k in 0..6 {
            let a = k as f64 * 0.35;
            let eye = [1.6 * a.cos(), 1.6 * a.sin(), 0.9];
            let beside = [eye[0] - 0.03 * a.sin(), eye[1] + 0.03 * a.cos(), eye[2]];
            for (name, at, rgb) in [
                (format!("thermal/{k}"), eye, false),
                (format!("rgb/{k}"), beside, true),
            ] {
                let (w, h) = if rgb { (64, 48) } else { (16, 12) };
                let camera =
                    PinholeCamera::look_at(at, [0.0, 0.0, 0.15], [0.0, 0.0, 1.0], w as f64, w, h);
                views.push(View {
                    name,
                    camera,
                    thermal: (!rgb).then(|| vec![0.5; w * h]),
                    rgb: rgb.then(|| vec![0.5; 3 * w * h]),
                });
            }
        }
        let data = Dataset {
            root: "mem".into(),
            train: (0..views.len()).collect(),
            test: Vec::new(),
            views,
            range: None,
            points_m: Vec::new(),
            point_rgb: Vec::new(),
            undistorted_models: Vec::new(),
            fresh_after_ffc: None,
        };
        let partners = modality_partners(&data, [0.0, 0.0, 0.15]);
        for (i, p) in partners.iter().enumerate() {
            let j = p.unwrap_or_else(|| panic!("{} has no partner", data.views[i].name));
            assert_eq!(
                j,
                i ^ 1,
                "{} pairs with {}, not its own instant's image",
                data.views[i].name,
                data.views[j].name
            );
        }
    }
}
