//! The Vulkan training backend: [`crate::train::backend::Backend`] over the GPU rasteriser, so
//! `s3tir-train --backend vulkan` runs the same training loop as the CPU backend.
//!
//! Thermal training steps run resident ([`Backend::resident_step`]): the parameters, the Adam
//! moments and the densification statistics stay on the GPU ([`super::optimiser`]); the
//! training view (and a [`Partner::Render`] partner) are rendered into buffers that stay there,
//! the single-view loss ([`super::loss`]) and the consistency term ([`super::consistency`])
//! write the upstream gradient planes, the backward passes write the parameter gradients into
//! the optimiser's buffers and the `adam` kernel steps the state. A [`Partner::Previous`]
//! partner is the previous step's training view: every step copies its view's planes and
//! camera block into one of two kept slots, and the next step's term reads the other (no
//! render, no backward pass for it; a repeated step reads the same slot). A step is three
//! submissions (binning, sorting and forward passes, then losses + backward passes + Adam) and one
//! small read at the end: the loss sums and the views' key totals. The key lists have the room
//! earlier steps measured, so the sort reads its count on the GPU; a step whose views need more
//! room is gated (the `adam` kernel changes nothing) and runs again with room for them. With
//! [`VulkanBackend::set_resident_optimiser`] off, steps take the device path
//! ([`Backend::device_step`]: the same, with the gradients read back for the host's Adam); with
//! [`VulkanBackend::set_device_losses`] off, the host path (images read back). Targets are uploaded
//! once per view. Primitives with an SH colour (joint RGB + thermal runs) take the host path:
//! [`Backend::render`] renders the thermal image, the G-buffers and the RGB planes on the GPU,
//! the losses run on the host and [`Backend::backward`] back-propagates every plane, the RGB
//! ones included, on the GPU; the device and resident steps are thermal-only and return an
//! error for primitives with colour.

use std::collections::HashMap;

use super::accumulate::AccumulateVariant;
use super::consistency::{ConsistencyViews, GpuConsistency};
use super::context::{ContextOptions, GpuBuffer, GpuContext, MemoryLocation, Recorder};
use super::error::GpuError;
use super::loss::{GpuViewLoss, LOSS_SLOTS};
use super::optimiser::{AdamStep, GpuOptimiser, KeyGate};
use super::raster::{GpuRasterizer, KeptView, KeySizing, Outputs, ParamSource};
use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::loss::response::ResponseGrad;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings};
use crate::train::backend::{
    Backend, DeviceStep, DeviceStepResult, OptimiserState, Partner, ResidentStep,
    ResidentStepResult, RunShape,
};

/// Bytes of a camera block ([`super::raster::camera_block`]).
const CAMERA_BLOCK_BYTES: u64 = 32 * 4;

/// Least room of a resident step's key lists (keys; 8 + 4 bytes each).
const KEY_ROOM_MIN: usize = 1024;

/// Leading u32 of `DeviceLosses::step_out`: the key totals of the step's (up to) two views.
const STEP_OUT_TOTALS: u64 = 2;

/// What a step's one read gives: its weighted loss, the response's gradient (when the step had
/// a response) and the views' key totals.
struct StepLosses {
    loss: f64,
    response: Option<ResponseGrad>,
    key_totals: [u32; 2],
}

/// Work recorded after the losses, in the same submission, with the kept views.
type RecordAfterLosses<'r> =
    dyn Fn(&mut Recorder<'_>, &[KeptView<'_>]) -> Result<(), GpuError> + 'r;

/// Loss kernels and buffers of the device path, for views of one size.
#[derive(Debug)]
struct DeviceLosses {
    width: usize,
    height: usize,
    view_loss: GpuViewLoss,
    consistency: GpuConsistency,
    /// Thermal targets by view index, uploaded on first use.
    targets: HashMap<usize, GpuBuffer>,
    /// Upstream gradient planes (6 each) of the reference and the paired view.
    up_i: GpuBuffer,
    up_j: GpuBuffer,
    /// Zero planes standing in for a view no primitive covers (the rasteriser keeps none).
    zeros: GpuBuffer,
    /// What a step reads back, in one read: the key totals of its two views (u32; 0 for a
    /// missing pair), then its loss sums (view loss [`LOSS_SLOTS`], consistency 2).
    step_out: GpuBuffer,
    /// The planes (Ψ … alpha, 6) of the last step's training view, for a
    /// [`Partner::Previous`] in the next: a step reads `kept[kept_slot]` and writes the other,
    /// which becomes `kept_slot` when the step completes (a repeated step reads the same).
    kept: [GpuBuffer; 2],
    /// Their camera blocks ([`super::raster::camera_block`]), slot by slot.
    kept_camera: [GpuBuffer; 2],
    kept_slot: usize,
    /// The camera of the view in `kept[kept_slot]` (`None`: nothing kept).
    kept_cam: Option<PinholeCamera>,
}

impl DeviceLosses {
    fn new(
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

    fn destroy(self, ctx: &GpuContext) {
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

/// Renders and back-propagates on a Vulkan device.
#[derive(Debug)]
pub struct VulkanBackend {
    // Field order: the rasteriser's kernels are released (Drop) before the context.
    raster: Option<GpuRasterizer>,
    losses: Option<DeviceLosses>,
    /// Parameters, moments and statistics on the GPU (built on the first upload).
    optimiser: Option<GpuOptimiser>,
    /// Whether thermal steps take the device path (default); off: host losses, as the CPU.
    device_losses: bool,
    /// Whether the optimiser state may stay on the GPU (default; needs `device_losses`).
    resident: bool,
    /// Steps taken with the optimiser state on the GPU.
    resident_steps: u64,
    /// Room of resident steps' key lists (0 until a step has measured it; see
    /// [`KeySizing::Capacity`]), and the primitive count it was measured with.
    key_room: (usize, usize),
    /// Resident steps repeated because a key list had no room (see `resident_step_inner`).
    repeated_steps: u64,
    ctx: GpuContext,
    pub settings: RenderSettings,
}

impl VulkanBackend {
    /// Opens the device of `options` and builds the kernels, choosing gradient accumulation
    /// with float atomics where the device has them (and `options` does not disable them).
    pub fn new(options: &ContextOptions, settings: RenderSettings) -> Result<Self, GpuError> {
        let ctx = GpuContext::new(options)?;
        let raster = GpuRasterizer::new(&ctx, AccumulateVariant::best_for(ctx.capabilities()))?;
        tracing::info!(device = %ctx.report().name, accumulate = ?raster.variant(), "Vulkan backend ready");
        Ok(Self {
            raster: Some(raster),
            losses: None,
            optimiser: None,
            device_losses: true,
            resident: true,
            resident_steps: 0,
            key_room: (0, 0),
            repeated_steps: 0,
            ctx,
            settings,
        })
    }

    /// Chooses whether thermal steps evaluate their losses on the GPU (the default) or on the
    /// host like the CPU backend (for comparisons and tests).
    pub fn set_device_losses(&mut self, on: bool) {
        self.device_losses = on;
    }

    /// Chooses whether the optimiser state (parameters, Adam moments, densification
    /// statistics) stays on the GPU between steps and Adam runs there (the default), or Adam
    /// runs on the host with the gradients read back every step (for comparisons and tests).
    pub fn set_resident_optimiser(&mut self, on: bool) {
        self.resident = on;
    }

    /// Steps taken so far with the optimiser state resident on the GPU.
    pub fn resident_steps(&self) -> u64 {
        self.resident_steps
    }

    /// Gives the next resident step's key lists room for `keys` keys per view, as if an
    /// earlier step had measured that (for tests: too little room makes the step run twice,
    /// the first run gated; see [`Self::repeated_steps`]).
    pub fn set_key_room(&mut self, keys: usize) {
        self.key_room = (keys.max(1), 0);
    }

    /// Buffers the rasteriser had to create (its released buffers serve the next views, so a
    /// warm step creates none).
    pub fn raster_buffers_created(&self) -> u64 {
        self.raster.as_ref().map_or(0, |r| r.buffers_created())
    }

    /// Resident steps run twice because a view's key list outgrew its room (the first run
    /// changed nothing): after density control, or when a view covers more tiles than any
    /// before.
    pub fn repeated_steps(&self) -> u64 {
        self.repeated_steps
    }

    /// Creates the loss buffers for the size of `step`'s views and uploads its target once.
    fn prepare_losses(&mut self, step: &DeviceStep<'_>) -> Result<(), GpuError> {
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
    fn forward_losses(
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

    /// A step on `cam` completed: the planes it kept are the next step's [`Partner::Previous`].
    fn step_kept(&mut self, cam: &PinholeCamera) {
        if let Some(l) = self.losses.as_mut() {
            l.kept_slot = 1 - l.kept_slot;
            l.kept_cam = Some(*cam);
        }
    }

    /// The device path of [`Backend::device_step`].
    fn device_step_inner(
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
    fn resident_step_inner(
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
    fn resident_attempt(
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

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Times every kernel dispatch from now on (for `s3tir-train bench`).
    pub fn set_profiling(&mut self, on: bool) {
        if let Some(r) = self.raster.as_mut() {
            r.set_profiling(on);
        }
    }

    /// Kernel timings collected since the last call.
    pub fn take_timings(&self) -> Vec<super::context::KernelTiming> {
        self.raster
            .as_ref()
            .map(|r| r.take_timings())
            .unwrap_or_default()
    }

    fn raster(&self) -> Result<&GpuRasterizer, RenderError> {
        self.raster.as_ref().ok_or_else(|| RenderError::Gpu {
            source: shut_down(),
        })
    }

    /// The device and resident steps evaluate thermal losses only (their `DeviceStep` has no
    /// RGB target) and keep no colour: a step of primitives with colour takes the host path
    /// (render, losses on the host, [`Backend::backward`]). Called with colour anyway, they
    /// return this error rather than gradients without the colour's losses.
    fn colour_refused(call: &str) -> RenderError {
        RenderError::Gpu {
            source: GpuError::InvalidInput {
                reason: format!(
                    "{call}: the primitives carry an SH colour; the Vulkan backend's device and \
                     resident steps are thermal-only — steps with colour take the host path \
                     (Backend::render, host losses, Backend::backward)"
                ),
            },
        }
    }
}

fn shut_down() -> GpuError {
    GpuError::InvalidInput {
        reason: "the Vulkan backend was already shut down".to_owned(),
    }
}

fn no_resident_state() -> GpuError {
    GpuError::InvalidInput {
        reason: "no optimiser state on the GPU (resident_upload first)".to_owned(),
    }
}

impl Backend for VulkanBackend {
    fn name(&self) -> &'static str {
        "vulkan"
    }

    /// Every per-primitive and per-pixel buffer of the run ([`super::raster::run_buffers`])
    /// within the device's storage-buffer range.
    fn check_run(&self, shape: &RunShape) -> Result<(), RenderError> {
        let report = self.ctx.report();
        let npix = shape.width * shape.height;
        let storage = super::raster::run_buffers(shape.budget, shape.bands, shape.sh_k, npix).map(
            |(b, r)| {
                let limit = report.max_storage_buffer_range_bytes;
                (b, r, "bytes", "maxStorageBufferRange", limit)
            },
        );
        let texel = super::raster::run_texel_buffers(shape.budget, shape.bands).map(|(b, r)| {
            let limit = report.max_texel_buffer_elements;
            (b, r, "texels", "maxTexelBufferElements", limit)
        });
        for (buffer, required, unit, limit, actual) in storage.into_iter().chain(texel) {
            if required > actual {
                return Err(GpuError::BudgetTooLarge {
                    device: report.name.clone(),
                    buffer,
                    budget: shape.budget,
                    bands: shape.bands,
                    limit,
                    unit,
                    required,
                    actual,
                }
                .into());
            }
        }
        // The run fits: its per-primitive buffers are created for the whole budget.
        if let Some(raster) = &self.raster {
            raster.reserve_primitives(shape.budget);
        }
        Ok(())
    }

    fn render(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, RenderError> {
        let _span = tracing::trace_span!("vulkan_render").entered();
        self.raster()?
            .render(&self.ctx, prims, cam, Outputs::All, &self.settings)
            .map_err(|source| RenderError::Gpu { source })
    }

    fn render_gbuffers(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, RenderError> {
        let _span = tracing::trace_span!("vulkan_render_gbuffers").entered();
        self.raster()?
            .render(&self.ctx, prims, cam, Outputs::GBuffers, &self.settings)
            .map_err(|source| RenderError::Gpu { source })
    }

    fn backward(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, RenderError> {
        let _span = tracing::trace_span!("vulkan_backward").entered();
        self.raster()?
            .render_backward(&self.ctx, prims, cam, &self.settings, upstream)
            .map_err(|source| RenderError::Gpu { source })
    }

    fn device_step(
        &mut self,
        prims: &Primitives<f32>,
        step: &DeviceStep<'_>,
    ) -> Option<Result<DeviceStepResult, RenderError>> {
        // The device path covers thermal-only steps whose two views share one size (its loss
        // buffers are sized per view size); anything else takes the host path.
        let same_size = step
            .pair
            .map(|p| p.camera())
            .is_none_or(|c| (c.width, c.height) == (step.cam.width, step.cam.height));
        if !self.device_losses || !same_size {
            return None;
        }
        if prims.sh_degree.is_some() {
            return Some(Err(Self::colour_refused("device_step")));
        }
        let _span = tracing::trace_span!("vulkan_device_step").entered();
        Some(
            self.device_step_inner(prims, step)
                .map_err(|source| RenderError::Gpu { source }),
        )
    }

    fn resident_upload(&mut self, state: &mut OptimiserState<'_>) -> Result<bool, RenderError> {
        if !(self.resident && self.device_losses) || state.prims.sh_degree.is_some() {
            return Ok(false);
        }
        let gpu = |source| RenderError::Gpu { source };
        if self.optimiser.is_none() {
            self.optimiser = Some(GpuOptimiser::new(&self.ctx).map_err(gpu)?);
        }
        let Some(opt) = self.optimiser.as_mut() else {
            return Ok(false);
        };
        opt.upload(
            &self.ctx,
            state.prims,
            state.adam,
            state.grad_accum,
            state.grad_count,
        )
        .map_err(gpu)?;
        Ok(true)
    }

    fn resident_step(
        &mut self,
        prims: &Primitives<f32>,
        step: &ResidentStep<'_>,
    ) -> Option<Result<ResidentStepResult, RenderError>> {
        let l = &step.losses;
        let same_size = l
            .pair
            .map(|p| p.camera())
            .is_none_or(|c| (c.width, c.height) == (l.cam.width, l.cam.height));
        let resident = self
            .optimiser
            .as_ref()
            .is_some_and(GpuOptimiser::is_resident);
        if !resident || !same_size {
            return None;
        }
        if prims.sh_degree.is_some() {
            return Some(Err(Self::colour_refused("resident_step")));
        }
        let _span = tracing::trace_span!("vulkan_resident_step").entered();
        Some(
            self.resident_step_inner(prims, step)
                .map_err(|source| RenderError::Gpu { source }),
        )
    }

    fn resident_download(&mut self, state: &mut OptimiserState<'_>) -> Result<(), RenderError> {
        let Some(opt) = self.optimiser.as_mut() else {
            return Ok(());
        };
        if !opt.is_resident() {
            return Ok(());
        }
        let out = opt.download(
            &self.ctx,
            state.prims,
            state.adam,
            state.grad_accum,
            state.grad_count,
        );
        opt.release(&self.ctx);
        out.map_err(|source| RenderError::Gpu { source })
    }
}

impl Drop for VulkanBackend {
    fn drop(&mut self) {
        if let Some(o) = self.optimiser.take() {
            o.destroy(&self.ctx);
        }
        if let Some(r) = self.raster.take() {
            r.destroy(&self.ctx);
        }
        if let Some(l) = self.losses.take() {
            l.destroy(&self.ctx);
        }
    }
}
