//! The device and resident training steps: the forward half ([`super::losses`]), the
//! backward passes, and the host's or the GPU's Adam; a resident step whose key lists had no
//! room runs again with room for them.

use super::*;

impl VulkanBackend {
    /// A step on `cam` completed: the planes it kept are the next step's [`Partner::Previous`].
    pub(super) fn step_kept(&mut self, cam: &PinholeCamera) {
        if let Some(l) = self.losses.as_mut() {
            l.kept_slot = 1 - l.kept_slot;
            l.kept_cam = Some(*cam);
        }
    }

    /// The device path of [`Backend::device_step`].
    pub(super) fn device_step_inner(
        &mut self,
        prims: &Primitives<f32>,
        step: &DeviceStep<'_>,
    ) -> Result<DeviceStepResult, GpuError> {
        self.prepare_losses(step)?;
        let step_losses =
            self.forward_losses(prims, ParamSource::Host, step, KeySizing::Exact, &|_, _| {
                Ok(())
            })?;
        self.step_kept(step.cam);
        let raster = self.raster.as_ref().ok_or_else(shut_down)?;
        let losses = self.losses.as_ref().ok_or_else(|| GpuError::InvalidInput {
            reason: "device losses unavailable".to_owned(),
        })?;
        let ctx = &self.ctx;
        let mut grads = raster.render_backward_device(
            ctx,
            prims,
            step.cam,
            Outputs::All,
            &self.settings,
            &losses.up_i,
        )?;
        if let Some(Partner::Render(cam_j)) = step.pair {
            let g_j = raster.render_backward_device(
                ctx,
                prims,
                cam_j,
                Outputs::GBuffers,
                &self.settings,
                &losses.up_j,
            )?;
            for ((_, a), (_, b)) in grads.groups_mut().into_iter().zip(g_j.groups()) {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += *y;
                }
            }
        }
        Ok(DeviceStepResult {
            loss: step_losses.loss,
            grads,
            response: step_losses.response,
        })
    }

    /// The path of [`Backend::resident_step`]: as [`Self::device_step_inner`] from the
    /// resident parameters, with the gradients written to the optimiser's buffers and the Adam
    /// step on the GPU.
    ///
    /// Host reads per step: one, of the loss values and the views' key totals, at the end. The
    /// key lists have the room the last steps measured ([`KeySizing::Capacity`]), scaled with
    /// the primitive count; if a view needs more, the `adam` kernel's [`KeyGate`] leaves the
    /// state untouched and the step runs again with room for it. The first step (nothing
    /// measured yet) sizes its lists exactly from a second read.
    pub(super) fn resident_step_inner(
        &mut self,
        prims: &Primitives<f32>,
        step: &ResidentStep<'_>,
    ) -> Result<ResidentStepResult, GpuError> {
        let losses_step = &step.losses;
        self.prepare_losses(losses_step)?;
        let n = prims.len();
        let (room, room_n) = self.key_room;
        let mut sizing = if room == 0 {
            KeySizing::Exact
        } else {
            // Keys grow with the primitives (density control): scale the room with them.
            let scaled = room.saturating_mul(n).checked_div(room_n).unwrap_or(room);
            KeySizing::Capacity(room.max(scaled))
        };
        loop {
            let attempt = self.resident_attempt(prims, step, sizing)?;
            let totals = attempt.key_totals;
            // A new generation either way: the views just kept must not stand in for the next
            // run's (a repeated step renders the same parameters again).
            if let Some(opt) = self.optimiser.as_mut() {
                opt.advance();
            }
            let need = totals.into_iter().max().unwrap_or(0) as usize;
            let fits = match sizing {
                KeySizing::Exact => true,
                KeySizing::Capacity(c) => need <= c,
            };
            let room = match sizing {
                KeySizing::Capacity(c) if fits => c,
                _ => (need + need / 4).max(KEY_ROOM_MIN),
            };
            self.key_room = (room, n);
            if fits {
                self.resident_steps += 1;
                self.step_kept(losses_step.cam);
                return Ok(ResidentStepResult {
                    loss: attempt.loss,
                    response: attempt.response,
                });
            }
            // Nothing changed on the GPU (the Adam step was gated): run it again.
            tracing::debug!(need, room, "key lists outgrew their room: step repeated");
            self.repeated_steps += 1;
            sizing = KeySizing::Capacity(room);
        }
    }

    /// One run of a resident step with key lists sized by `sizing`; returns the losses and the
    /// views' key totals. With [`KeySizing::Capacity`] the Adam step is gated on the totals.
    pub(super) fn resident_attempt(
        &self,
        prims: &Primitives<f32>,
        step: &ResidentStep<'_>,
        sizing: KeySizing,
    ) -> Result<StepLosses, GpuError> {
        let losses_step = &step.losses;
        let opt = self.optimiser.as_ref().ok_or_else(no_resident_state)?;
        let (params, generation) = opt.params().ok_or_else(no_resident_state)?;
        let src = ParamSource::Device {
            buffer: params,
            generation,
        };
        let raster = self.raster.as_ref().ok_or_else(shut_down)?;
        let losses = self.losses.as_ref().ok_or_else(|| GpuError::InvalidInput {
            reason: "device losses unavailable".to_owned(),
        })?;
        let (grads_i, grads_j) = opt.grads().ok_or_else(no_resident_state)?;
        let (acc_i, acc_j) = opt.scratch().ok_or_else(no_resident_state)?;
        let adam = AdamStep {
            sizes: step.sizes,
            hp: step.hp,
            min_log_scale: step.min_log_scale,
            band_shrink: step.band_shrink,
        };
        let gate = match sizing {
            KeySizing::Exact => None,
            KeySizing::Capacity(c) => Some(KeyGate {
                totals: &losses.step_out,
                capacity: u32::try_from(c).unwrap_or(u32::MAX),
                views: STEP_OUT_TOTALS as u32,
            }),
        };
        // Losses, both backward passes and Adam in one submission.
        self.forward_losses(prims, src, losses_step, sizing, &|rec, views| {
            rec.compute_barrier();
            let written_i = raster.record_backward(
                rec,
                prims,
                &views[0],
                Outputs::All,
                &losses.up_i,
                acc_i,
                grads_i,
            )?;
            let written_j = match views.get(1) {
                Some(view_j) => raster.record_backward(
                    rec,
                    prims,
                    view_j,
                    Outputs::GBuffers,
                    &losses.up_j,
                    acc_j,
                    grads_j,
                )?,
                None => false,
            };
            opt.record_step(
                rec,
                &adam,
                losses_step.cam,
                written_i,
                written_j,
                gate.as_ref(),
            )
        })
    }
}
