//! The device losses of a step: the buffers they need (sized once per view size, the target
//! uploaded once per view), and the forward half of a device or resident step — the views
//! rendered and kept on the GPU, the single-view loss and the consistency term writing the
//! upstream planes — with its one read.

use super::*;

/// What a step's one read gives: its weighted loss, the response's gradient (when the step had
/// a response) and the views' key totals.
pub(super) struct StepLosses {
    pub(super) loss: f64,
    pub(super) response: Option<ResponseGrad>,
    pub(super) key_totals: [u32; 2],
}

/// Work recorded after the losses, in the same submission, with the kept views.
type RecordAfterLosses<'r> =
    dyn Fn(&mut Recorder<'_>, &[KeptView<'_>]) -> Result<(), GpuError> + 'r;

/// Loss kernels and buffers of the device path, for views of one size.
#[derive(Debug)]
pub(super) struct DeviceLosses {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) view_loss: GpuViewLoss,
    pub(super) consistency: GpuConsistency,
    /// Thermal targets by view index, uploaded on first use.
    pub(super) targets: HashMap<usize, GpuBuffer>,
    /// Upstream gradient planes (6 each) of the reference and the paired view.
    pub(super) up_i: GpuBuffer,
    pub(super) up_j: GpuBuffer,
    /// Zero planes standing in for a view no primitive covers (the rasteriser keeps none).
    pub(super) zeros: GpuBuffer,
    /// What a step reads back, in one read: the key totals of its two views (u32; 0 for a
    /// missing pair), then its loss sums (view loss [`LOSS_SLOTS`], consistency 2).
    pub(super) step_out: GpuBuffer,
    /// The planes (Ψ … alpha, 6) of the last step's training view, for a
    /// [`Partner::Previous`] in the next: a step reads `kept[kept_slot]` and writes the other,
    /// which becomes `kept_slot` when the step completes (a repeated step reads the same).
    pub(super) kept: [GpuBuffer; 2],
    /// Their camera blocks ([`super::raster::camera_block`]), slot by slot.
    pub(super) kept_camera: [GpuBuffer; 2],
    pub(super) kept_slot: usize,
    /// The camera of the view in `kept[kept_slot]` (`None`: nothing kept).
    pub(super) kept_cam: Option<PinholeCamera>,
}

impl DeviceLosses {
    pub(super) fn new(
        ctx: &GpuContext,
        variant: AccumulateVariant,
        width: usize,
        height: usize,
    ) -> Result<Self, GpuError> {
        let bytes = (6 * width * height * 4) as u64;
        let view_loss = GpuViewLoss::new(ctx, width, height)?;
        let consistency = match GpuConsistency::new(ctx, variant, width, height) {
            Ok(c) => c,
            Err(e) => {
                view_loss.destroy(ctx);
                return Err(e);
            }
        };
        let mut buffers = Vec::new();
        for (name, size) in [
            ("device_step.up_i", bytes),
            ("device_step.up_j", bytes),
            ("device_step.zeros", (7 * width * height * 4) as u64),
            (
                "device_step.loss_sums",
                (STEP_OUT_TOTALS + LOSS_SLOTS as u64 + 2) * 4,
            ),
            ("device_step.kept_a", bytes),
            ("device_step.kept_b", bytes),
            ("device_step.kept_camera_a", CAMERA_BLOCK_BYTES),
            ("device_step.kept_camera_b", CAMERA_BLOCK_BYTES),
        ] {
            let location = if name.ends_with("loss_sums") {
                MemoryLocation::Readback
            } else {
                MemoryLocation::DeviceOnly
            };
            match ctx.create_buffer(name, size, location) {
                Ok(b) => buffers.push(b),
                Err(e) => {
                    buffers.into_iter().for_each(|b| ctx.destroy_buffer(b));
                    view_loss.destroy(ctx);
                    consistency.destroy(ctx);
                    return Err(e);
                }
            }
        }
        let mut b = buffers.into_iter();
        let (
            Some(up_i),
            Some(up_j),
            Some(zeros),
            Some(step_out),
            Some(kept_a),
            Some(kept_b),
            Some(kept_camera_a),
            Some(kept_camera_b),
        ) = (
            b.next(),
            b.next(),
            b.next(),
            b.next(),
            b.next(),
            b.next(),
            b.next(),
            b.next(),
        )
        else {
            view_loss.destroy(ctx);
            consistency.destroy(ctx);
            return Err(GpuError::InvalidInput {
                reason: "device losses: buffer list incomplete".to_owned(),
            });
        };
        Ok(Self {
            width,
            height,
            view_loss,
            consistency,
            targets: HashMap::new(),
            up_i,
            up_j,
            zeros,
            step_out,
            kept: [kept_a, kept_b],
            kept_camera: [kept_camera_a, kept_camera_b],
            kept_slot: 0,
            kept_cam: None,
        })
    }

    pub(super) fn destroy(self, ctx: &GpuContext) {
        self.view_loss.destroy(ctx);
        self.consistency.destroy(ctx);
        for b in self.targets.into_values() {
            ctx.destroy_buffer(b);
        }
        ctx.destroy_buffer(self.up_i);
        ctx.destroy_buffer(self.up_j);
        ctx.destroy_buffer(self.zeros);
        ctx.destroy_buffer(self.step_out);
        for b in self.kept.into_iter().chain(self.kept_camera) {
            ctx.destroy_buffer(b);
        }
    }
}

impl VulkanBackend {
    /// Creates the loss buffers for the size of `step`'s views and uploads its target once.
    pub(super) fn prepare_losses(&mut self, step: &DeviceStep<'_>) -> Result<(), GpuError> {
        let (w, h) = (step.cam.width, step.cam.height);
        let npix = w * h;
        if step.target.len() != npix {
            return Err(GpuError::InvalidInput {
                reason: format!(
                    "thermal target of view {} has {} values, its {w}x{h} camera needs {npix}",
                    step.view,
                    step.target.len()
                ),
            });
        }
        let raster = self.raster.as_ref().ok_or_else(shut_down)?;
        let ctx = &self.ctx;
        if self
            .losses
            .as_ref()
            .is_some_and(|l| (l.width, l.height) != (w, h))
            && let Some(old) = self.losses.take()
        {
            old.destroy(ctx);
        }
        if self.losses.is_none() {
            self.losses = Some(DeviceLosses::new(ctx, raster.variant(), w, h)?);
        }
        let losses = self.losses.as_mut().ok_or_else(|| GpuError::InvalidInput {
            reason: "device losses unavailable".to_owned(),
        })?;
        if let std::collections::hash_map::Entry::Vacant(slot) = losses.targets.entry(step.view) {
            slot.insert(ctx.upload("device_step.target", step.target)?);
        }
        Ok(())
    }

    /// Renders the views of `step` (kept on the GPU, key lists sized by `sizing`) from the
    /// parameters of `src`, records the losses, which write the upstream planes `up_i` /
    /// `up_j`, then `after` in the same submission; returns the weighted loss and the views'
    /// key totals, from one read. `after` finds the key totals in the first
    /// [`STEP_OUT_TOTALS`] u32 of `step_out` (for [`KeyGate`]).
    // Why this stays long: one submission recorded in order (render each view, then each loss
    // term with its barrier, then `after`), followed by its single read; splitting the
    // recording would split the borrow of the step's buffers across closures.
    pub(super) fn forward_losses(
        &self,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        step: &DeviceStep<'_>,
        sizing: KeySizing,
        after: &RecordAfterLosses<'_>,
    ) -> Result<StepLosses, GpuError> {
        let raster = self.raster.as_ref().ok_or_else(shut_down)?;
        let losses = self.losses.as_ref().ok_or_else(|| GpuError::InvalidInput {
            reason: "device losses unavailable".to_owned(),
        })?;
        let ctx = &self.ctx;
        let target = losses
            .targets
            .get(&step.view)
            .ok_or_else(|| GpuError::InvalidInput {
                reason: "thermal target not uploaded".to_owned(),
            })?;
        // Views rendered now stay on the GPU for the losses and the backward passes. Only the
        // partner's G-buffers enter the loss: it is rendered without its thermal image, or
        // not at all when they were kept from the previous step.
        let pair = step.pair;
        let mut cams = vec![(step.cam, Outputs::All)];
        if let Some(Partner::Render(c)) = pair {
            cams.push((c, Outputs::GBuffers));
        }
        let previous = match pair {
            Some(Partner::Previous(c)) => {
                if losses.kept_cam.as_ref() != Some(c) {
                    return Err(GpuError::InvalidInput {
                        reason: "consistency partner: the previous step's training view is not \
                                 the one kept on the GPU (the loop pairs only consecutive device \
                                 steps)"
                            .to_owned(),
                    });
                }
                let slot = losses.kept_slot;
                Some((c, &losses.kept_camera[slot], &losses.kept[slot]))
            }
            _ => None,
        };
        let keep_into = &losses.kept[1 - losses.kept_slot];
        let keep_camera_into = &losses.kept_camera[1 - losses.kept_slot];
        raster.render_kept(ctx, prims, src, &cams, &self.settings, sizing)?;
        let zeros = &losses.zeros;
        raster.submit_with_views(ctx, prims, src, &cams, &self.settings, |rec, views| {
            fn planes_of<'a>(v: &KeptView<'a>, zeros: &'a GpuBuffer) -> &'a GpuBuffer {
                v.planes.unwrap_or(zeros)
            }
            let view_i = &views[0];
            rec.fill_zero(zeros);
            rec.fill_zero(&losses.up_j);
            rec.fill_zero(&losses.step_out);
            for (v, view) in views.iter().enumerate() {
                if let Some(total) = view.key_total {
                    rec.copy_region(total, 0, &losses.step_out, 4 * v as u64, 4)?;
                }
            }
            losses.view_loss.record(
                rec,
                planes_of(view_i, zeros),
                target,
                &losses.up_i,
                &step.weights,
                step.response.as_ref(),
            )?;
            // The partner: rendered now (view 1, gets gradients) or kept (stop-gradient).
            let partner = match (views.get(1), previous) {
                (Some(view_j), _) => Some((
                    view_j.camera,
                    planes_of(view_j, zeros),
                    Some(&losses.up_j),
                    view_j.width,
                    view_j.height,
                )),
                (None, Some((cam, camera, planes))) => {
                    Some((camera, planes, None, cam.width, cam.height))
                }
                (None, None) => None,
            };
            if let Some((cam_j, planes_j, up_j, width_j, height_j)) = partner {
                rec.compute_barrier();
                losses.consistency.record(
                    rec,
                    &ConsistencyViews {
                        cam_i: view_i.camera,
                        cam_j,
                        planes_i: planes_of(view_i, zeros),
                        planes_j,
                        up_i: &losses.up_i,
                        up_j,
                        width_j,
                        height_j,
                    },
                    &step.consistency,
                    step.weights.lambda_consist as f32,
                )?;
            }
            // Keep this view's planes for the next step's partner (the copy waits for the
            // consistency kernel's reads of the other slot; the slots differ anyway).
            rec.copy_region(
                planes_of(view_i, zeros),
                0,
                keep_into,
                0,
                keep_into.size_bytes(),
            )?;
            rec.copy_region(view_i.camera, 0, keep_camera_into, 0, CAMERA_BLOCK_BYTES)?;
            after(rec, views)?;
            let sums_at = 4 * STEP_OUT_TOTALS;
            let view_bytes = 4 * LOSS_SLOTS as u64;
            rec.copy_region(
                losses.view_loss.sums_buffer(),
                0,
                &losses.step_out,
                sums_at,
                view_bytes,
            )?;
            if pair.is_some() {
                let at = sums_at + view_bytes;
                rec.copy_region(losses.consistency.sums_buffer(), 0, &losses.step_out, at, 8)?;
            }
            Ok(())
        })?;
        let out: Vec<f32> =
            ctx.read(&losses.step_out, STEP_OUT_TOTALS as usize + LOSS_SLOTS + 2)?;
        let (totals, sums) = out.split_at(STEP_OUT_TOTALS as usize);
        let values = losses
            .view_loss
            .values_from(&sums[..LOSS_SLOTS], step.response.is_some());
        let mut loss = values.total(&step.weights);
        if pair.is_some() {
            loss += step.weights.lambda_consist
                * losses.consistency.values_from(&sums[LOSS_SLOTS..]).loss;
        }
        Ok(StepLosses {
            loss,
            response: values.response,
            key_totals: [totals[0].to_bits(), totals[1].to_bits()],
        })
    }
}
