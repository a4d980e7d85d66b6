//! One training step: the view and its consistency partner drawn, the step run where the
//! optimiser state lives (resident on the backend's device, else the device path or the host
//! path for the gradients with Adam on the host), the view's own terms, and the G-buffers kept
//! for the next step's partner.

use super::*;

/// A training view's G-buffers kept from its step for the next step's consistency term.
#[derive(Debug)]
pub(super) struct KeptView {
    pub(super) view: usize,
    /// Iteration of the step that rendered it.
    pub(super) iteration: u64,
    /// That step itself had a consistency term (it followed another): the next step draws a
    /// fresh view instead of following it, so the schedule alternates.
    pub(super) followed: bool,
    /// The host's copy (host path); `None`: the backend's device keeps them
    /// ([`Backend::device_step`]).
    pub(super) gbuffers: Option<GBuffers<f32>>,
}

/// The consistency partner a step uses (index into `data.views`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PairChoice {
    /// Rendered in this step.
    Render(usize),
    /// The previous step's training view, from its kept G-buffers.
    Previous(usize),
}

impl PairChoice {
    pub(super) fn view(self) -> usize {
        match self {
            PairChoice::Render(v) | PairChoice::Previous(v) => v,
        }
    }
}

impl<B: Backend> Trainer<B> {
    /// Records the step's training view `vi` as kept for the next step (`gbuffers`: the host's
    /// copy; `None`: the backend's device keeps them).
    pub(super) fn keep(&mut self, vi: usize, followed: bool, gbuffers: Option<GBuffers<f32>>) {
        self.kept = Some(KeptView {
            view: vi,
            iteration: self.iteration,
            followed,
            gbuffers,
        });
    }

    /// Loss and upstream gradient (into `up`) of one view's own terms, the gradient of its
    /// response (when the run learns one) and, for an RGB view, of the RGB background colour.
    pub(super) fn view_terms(
        &self,
        vi: usize,
        gb: &GBuffers<f32>,
        weights: &LossWeights,
        up: &mut GBuffers<f32>,
    ) -> Result<ViewTerms, TrainError> {
        let view = &self.data.views[vi];
        let mut loss = 0.0;
        let mut response = None;
        let mut rgb_background_grad = None;
        if let Some(target) = &view.thermal {
            let mut thermal = 0.0;
            match self.view_response(vi) {
                Some(r) => {
                    let (l, g) = view_loss_with_response(gb, target, weights, &r, up)?;
                    thermal += l.total;
                    response = Some(g);
                }
                None => thermal += view_loss(gb, target, weights, up)?.total,
            }
            let wa = self.thermal_align_weight();
            if wa > 0.0 {
                let a = thermal_align(gb, target, &view.camera, &AlignSettings::default(), wa, up)?;
                thermal += a.loss;
            }
            // The modality weight scales every term of the view (one view, one modality).
            let wt = self.cfg.joint.thermal_weight;
            if wt != 1.0 {
                for (_, plane) in up.planes_mut() {
                    plane.iter_mut().for_each(|g| *g *= wt as f32);
                }
                if let Some(g) = response.as_mut() {
                    g.gain *= wt;
                    g.offset *= wt;
                }
            }
            loss += wt * thermal;
        }
        if let (Some(target), false) = (&view.rgb, gb.rgb.is_empty()) {
            let (l, g) = self.rgb_terms(gb, target, weights, up)?;
            loss += l;
            rgb_background_grad = Some(g);
        }
        Ok(ViewTerms {
            loss,
            response,
            background: rgb_background_grad,
        })
    }

    /// View `vi`'s learned response (`None`: the run learns none).
    pub(super) fn view_response(&self, vi: usize) -> Option<ViewResponse> {
        self.state.response.as_ref().map(|m| m.of_view(vi))
    }

    /// One optimisation step on one training view; returns its loss.
    ///
    /// Thermal steps on a backend that keeps the optimiser state on its device
    /// ([`Backend::resident_step`]) run there whole: losses, backward, densification
    /// statistics and Adam. Otherwise the backend's device path ([`Backend::device_step`]) or
    /// the host path computes the gradients and Adam runs on the host.
    pub fn step(&mut self) -> Result<f64, TrainError> {
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.cfg.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ self.iteration,
        );
        let drawn = self.draw_view(&mut rng);
        if self.state.warmup_ended_at.is_none() && self.after_warmup() {
            self.state.warmup_ended_at = Some(self.iteration);
            // Only after a warm-up: with none, β and the bands were live from the start, and
            // what is frozen or band-free now was made so on purpose (`keep_bands_on`).
            let warm_up = self.cfg.warmup > 0;
            let bands = if self.cfg.mode.has_bands() && warm_up {
                self.cfg.bands
            } else {
                0
            };
            let beta = self.cfg.mode.learns_beta() && warm_up;
            if beta || bands > 0 {
                self.sync_host()?;
            }
            if beta {
                self.release_warmup_beta();
            }
            // Only when the warm-up switched them off (not with `warmup` 0, nor in a run
            // checkpointed before band slots were switched off during the warm-up); a run
            // checkpointed when the idle slots were still stored has them already.
            if bands > 0 && self.prims.band_count.iter().all(|&c| c == 0) {
                self.release_warmup_bands(bands);
            }
        }
        let weights = self.loss_weights();
        let has_rgb = !self.prims.sh.is_empty();
        let (vi, pair) = self.schedule(drawn, &mut rng);
        // A partner kept on the host (the last step took the host path) needs the host path.
        let host_kept = matches!(pair, Some(PairChoice::Previous(_)))
            && self.kept.as_ref().is_some_and(|k| k.gbuffers.is_some());
        let thermal_only = self.data.views[vi].thermal.is_some()
            && !has_rgb
            && !host_kept
            && !self.host_losses_only();
        if thermal_only && !self.resident {
            self.resident = self.backend.resident_upload(&mut OptimiserState {
                prims: &mut self.prims,
                adam: &mut self.adam,
                grad_accum: &mut self.grad_accum,
                grad_count: &mut self.grad_count,
            })?;
        }
        let lrs = self.lrs();
        let cam_i = self.data.views[vi].camera;
        let response = self.view_response(vi);
        let mut resident_loss = None;
        if let (Some(losses), true) = (
            thermal_step(&self.data, vi, pair, weights, &cam_i, response),
            self.resident && !self.host_losses_only(),
        ) {
            let hp = self.adam_params();
            let step = ResidentStep {
                losses,
                sizes: self.adam.step_sizes(&lrs, &hp),
                band_shrink: self.adam.band_shrink(&lrs, &hp),
                hp,
                min_log_scale: self.min_log_scale,
            };
            resident_loss = self.backend.resident_step(&self.prims, &step).transpose()?;
        }
        let (loss, response_grad) = match resident_loss {
            Some(r) => {
                self.adam.advance(&lrs);
                self.keep(vi, pair.is_some(), None);
                (r.loss, r.response)
            }
            None => {
                self.sync_host()?;
                self.host_optimiser_step(vi, pair, &weights, &lrs, host_kept)?
            }
        };
        let decay = self.cfg.response.lr_final_ratio.powf(self.progress());
        if let (Some(model), Some(g)) = (self.state.response.as_mut(), response_grad) {
            model.step(&self.cfg.response, vi, g, decay);
        }
        self.decide_response();
        self.iteration += 1;

        if self.densify_due() {
            self.sync_host()?;
            self.densify(&mut rng);
        }
        if self.grant_due() {
            self.sync_host()?;
            self.grant_bands();
            self.drop_bands();
        }
        if self.capacity_due() {
            self.state.capacity_checks += 1;
            self.sync_host()?;
            // Before the grant the amplitudes are still being measured.
            if self.prims.bands > 0 && self.bands_granted() {
                self.drop_bands();
            }
            if self.cfg.mode.learns_beta() {
                self.freeze_gaussians();
            }
            self.note_gaussian_run();
        }
        Ok(loss)
    }

    /// Gradients (the backend's device path, else render + host losses + backward),
    /// densification statistics and Adam on the host; returns the loss and the gradient of
    /// the view's response. `host_kept`: the partner is the host's kept copy (no device path).
    pub(super) fn host_optimiser_step(
        &mut self,
        vi: usize,
        pair: Option<PairChoice>,
        weights: &LossWeights,
        lrs: &GroupLrs,
        host_kept: bool,
    ) -> Result<(f64, Option<ResponseGrad>), TrainError> {
        let weights = *weights;
        let cam_i = self.data.views[vi].camera;
        let has_rgb = !self.prims.sh.is_empty();
        // The backend's device path when it has one (images stay on the device), else the
        // host path below: render, losses on the host, backward.
        let response = self.view_response(vi);
        let device = match (
            thermal_step(&self.data, vi, pair, weights, &cam_i, response),
            has_rgb,
        ) {
            (Some(step), false) if !host_kept && !self.host_losses_only() => {
                self.backend.device_step(&self.prims, &step).transpose()?
            }
            _ => None,
        };
        let kept = self.kept.take();
        let (loss, grads, response_grad) = match device {
            Some(r) => {
                self.keep(vi, pair.is_some(), None);
                (r.loss, r.grads, r.response)
            }
            None => {
                let gb_i = self.backend.render(&self.prims, &cam_i)?;
                let mut up_i = GBuffers::zeros(gb_i.width, gb_i.height, has_rgb);
                let terms = self.view_terms(vi, &gb_i, &weights, &mut up_i)?;
                if let (Some(bg), Some(g)) = (self.state.background.as_mut(), terms.background) {
                    bg.step(g);
                }
                let (mut loss, response_grad) = (terms.loss, terms.response);

                let mut grads = None;
                if let Some(PairChoice::Previous(vj)) = pair {
                    match kept.as_ref().and_then(|k| k.gbuffers.as_ref()) {
                        Some(gb_j) => {
                            // The kept side is under stop-gradient: its upstream is dropped.
                            let cam_j = self.data.views[vj].camera;
                            let mut dropped = GBuffers::zeros(gb_j.width, gb_j.height, false);
                            let c = consistency_loss(
                                &gb_i,
                                &cam_i,
                                gb_j,
                                &cam_j,
                                &ConsistencyOptions::default(),
                                weights.lambda_consist as f32,
                                &mut up_i,
                                &mut dropped,
                            )?;
                            loss += weights.lambda_consist * c.loss;
                        }
                        // Kept on the backend's device, which this step does not use.
                        None => tracing::debug!(
                            iteration = self.iteration,
                            "consistency partner not kept on the host: term skipped"
                        ),
                    }
                }
                if let Some(PairChoice::Render(vj)) = pair {
                    let cam_j = self.data.views[vj].camera;
                    // Only the partner's G-buffers enter the loss.
                    let gb_j = self.backend.render_gbuffers(&self.prims, &cam_j)?;
                    let mut up_j = GBuffers::zeros(gb_j.width, gb_j.height, has_rgb);
                    let c = consistency_loss(
                        &gb_i,
                        &cam_i,
                        &gb_j,
                        &cam_j,
                        &ConsistencyOptions::default(),
                        weights.lambda_consist as f32,
                        &mut up_i,
                        &mut up_j,
                    )?;
                    loss += weights.lambda_consist * c.loss;
                    grads = Some(self.backend.backward(&self.prims, &cam_j, &up_j)?);
                }
                let g_i = self.backend.backward(&self.prims, &cam_i, &up_i)?;
                if self.align_share_due(vi) {
                    self.measure_align_share(vi, &gb_i, &g_i)?;
                }
                self.keep(vi, pair.is_some(), Some(gb_i));
                let mut grads = match grads {
                    None => g_i,
                    Some(mut g) => {
                        add_grads(&mut g, &g_i);
                        g
                    }
                };
                // Joint runs: the view of the other modality taken with this one trains in
                // the same step (one loss over both images, as the paper's end-to-end phase).
                if let Some(vr) = self.modality_partner(vi) {
                    let (l, g) = self.partner_gradients(vr, &weights)?;
                    loss += l;
                    add_grads(&mut grads, &g);
                }
                (loss, grads, response_grad)
            }
        };

        self.accumulate_densify_stats(&cam_i, &grads.means);

        let hp = self.adam_params();
        self.adam.step(&mut self.prims, &grads, lrs, &hp);
        for s in &mut self.prims.log_scales {
            *s = s.max(self.min_log_scale);
        }
        Ok((loss, response_grad))
    }
}

/// What one view's own terms give ([`Trainer::view_terms`]).
pub(super) struct ViewTerms {
    pub(super) loss: f64,
    /// The gradient of the view's response (thermal views of a run that learns one).
    pub(super) response: Option<ResponseGrad>,
    /// The gradient of the RGB background colour (RGB views).
    pub(super) background: Option<[f64; 3]>,
}

/// `a += b`, group by group.
fn add_grads(a: &mut Primitives<f32>, b: &Primitives<f32>) {
    for ((_, x), (_, y)) in a.groups_mut().into_iter().zip(b.groups()) {
        for (p, q) in x.iter_mut().zip(y) {
            *p += *q;
        }
    }
}

/// The thermal losses of a step on view `vi` (and its consistency partner `pair`) for a
/// backend's device ([`Backend::device_step`], [`Backend::resident_step`]); `None` when the view
/// has no thermal image.
fn thermal_step<'a>(
    data: &'a Dataset,
    vi: usize,
    pair: Option<PairChoice>,
    weights: LossWeights,
    cam: &'a PinholeCamera,
    response: Option<ViewResponse>,
) -> Option<DeviceStep<'a>> {
    data.views[vi].thermal.as_ref().map(|target| DeviceStep {
        view: vi,
        cam,
        target,
        pair: pair.map(|p| {
            let cam = &data.views[p.view()].camera;
            match p {
                PairChoice::Render(_) => Partner::Render(cam),
                PairChoice::Previous(_) => Partner::Previous(cam),
            }
        }),
        weights,
        consistency: ConsistencyOptions::default(),
        response,
    })
}
