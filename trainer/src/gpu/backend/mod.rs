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
//!
//! Here: the backend, its settings and the host path; `losses`: the loss buffers and a step's
//! forward half (views rendered and kept, losses writing the upstream planes, the one read);
//! `steps`: the device and resident steps built on it.

mod losses;
mod steps;

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
use losses::{DeviceLosses, StepLosses};

/// Bytes of a camera block ([`super::raster::camera_block`]).
const CAMERA_BLOCK_BYTES: u64 = 32 * 4;

/// Least room of a resident step's key lists (keys; 8 + 4 bytes each).
const KEY_ROOM_MIN: usize = 1024;

/// Leading u32 of `DeviceLosses::step_out`: the key totals of the step's (up to) two views.
const STEP_OUT_TOTALS: u64 = 2;

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
