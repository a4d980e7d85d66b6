//! The Vulkan training backend: [`crate::train::backend::Backend`] over the GPU rasteriser, so
//! `s3tir-train --backend vulkan` runs the same training loop as the CPU backend.
//!
//! This first version keeps the loop's host-side interface: the image and G-buffers come back
//! to the host for the losses and the upstream gradients go up again each step. The GPU loss
//! kernels ([`super::loss`]) and a GPU optimiser step remove those transfers next.

use super::accumulate::AccumulateVariant;
use super::context::{ContextOptions, GpuContext};
use super::error::GpuError;
use super::raster::GpuRasterizer;
use crate::camera::PinholeCamera;
use crate::error::TrainerError;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings};
use crate::train::backend::Backend;

/// Renders and back-propagates on a Vulkan device.
#[derive(Debug)]
pub struct VulkanBackend {
    // Field order: the rasteriser's kernels are released (Drop) before the context.
    raster: Option<GpuRasterizer>,
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
            ctx,
            settings,
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

    fn raster(&self) -> Result<&GpuRasterizer, TrainerError> {
        self.raster.as_ref().ok_or_else(|| TrainerError::Gpu {
            source: GpuError::InvalidInput {
                reason: "the Vulkan backend was already shut down".to_owned(),
            },
        })
    }

    fn check_no_colour(prims: &Primitives<f32>) -> Result<(), TrainerError> {
        if prims.sh_degree.is_some() {
            return Err(TrainerError::Gpu {
                source: GpuError::InvalidInput {
                    reason:
                        "primitives carry RGB colour (SH); the Vulkan backend renders thermal and \
                             G-buffers only so far — train RGB on the CPU backend"
                            .to_owned(),
                },
            });
        }
        Ok(())
    }
}

impl Backend for VulkanBackend {
    fn name(&self) -> &'static str {
        "vulkan"
    }

    fn render(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, TrainerError> {
        let _span = tracing::trace_span!("vulkan_render").entered();
        Self::check_no_colour(prims)?;
        self.raster()?
            .render(&self.ctx, prims, cam, &self.settings)
            .map_err(|source| TrainerError::Gpu { source })
    }

    fn backward(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, TrainerError> {
        let _span = tracing::trace_span!("vulkan_backward").entered();
        Self::check_no_colour(prims)?;
        self.raster()?
            .render_backward(&self.ctx, prims, cam, &self.settings, upstream)
            .map_err(|source| TrainerError::Gpu { source })
    }
}

impl Drop for VulkanBackend {
    fn drop(&mut self) {
        if let Some(r) = self.raster.take() {
            r.destroy(&self.ctx);
        }
    }
}
