//! The multi-view frequency consistency term on the GPU (`crate::loss::consistency_loss` as a
//! kernel): reference view i is warped into source view j by its expected depth, and
//! `|Ψ_high_i − Ψ_high_j∘warp| + |Ψ_β_i − Ψ_β_j∘warp|` is averaged over view i's pixels. The
//! gradients go straight into both views' upstream planes (the backward rasteriser's layout):
//! view i's by plain writes, view j's by scatter-add through the bilinear weights, with
//! `atomicAdd(float)` or a compare-and-swap loop (the variant of the backward rasteriser). The
//! loss and the number of unmasked pixels are reduced on the GPU and read back only when asked.
//!
//! The views are read in `raster_forward`'s plane layout, so the rasteriser's planes can be used
//! as they are; the warp runs in f32 where the CPU reference uses f64 (a pixel whose footprint
//! lies exactly on a mask boundary may be decided differently).

use super::accumulate::AccumulateVariant;
use super::context::{ComputeKernel, GpuBuffer, GpuContext, MemoryLocation, Recorder};
use super::error::GpuError;
use super::reduce::{GpuSum, ReduceVariant};
use super::shaders::{self, push_u32s};
use crate::loss::consistency::{Consistency, ConsistencyOptions};

const WG_2D: usize = 16;

/// The consistency kernel with its scratch buffers, for reference views of one size.
#[derive(Debug)]
pub struct GpuConsistency {
    kernel: ComputeKernel,
    sum: GpuSum,
    /// Per-pixel terms and valid flags of the reference view (2 planes).
    terms: GpuBuffer,
    /// Loss sum and valid-pixel count.
    sums: GpuBuffer,
    width: usize,
    height: usize,
}

/// The views of one consistency evaluation, as GPU buffers.
#[derive(Debug, Clone, Copy)]
pub struct ConsistencyViews<'a> {
    /// Camera blocks ([`super::raster::camera_block`]) of the reference and the source view.
    pub cam_i: &'a GpuBuffer,
    pub cam_j: &'a GpuBuffer,
    /// Planes of the views in `raster_forward`'s layout (at least Ψ_high … alpha).
    pub planes_i: &'a GpuBuffer,
    pub planes_j: &'a GpuBuffer,
    /// Upstream gradient planes (6-plane layout) the gradients are added to; distinct buffers.
    /// `up_j` `None`: the source view is under stop-gradient (its G-buffers were kept from an
    /// earlier step; see [`crate::train::Partner::Previous`]) and gets nothing.
    pub up_i: &'a GpuBuffer,
    pub up_j: Option<&'a GpuBuffer>,
    /// Size of the source view.
    pub width_j: usize,
    pub height_j: usize,
}

impl GpuConsistency {
    /// Builds the kernel of `variant` for reference views of `width`×`height`.
    pub fn new(
        ctx: &GpuContext,
        variant: AccumulateVariant,
        width: usize,
        height: usize,
    ) -> Result<Self, GpuError> {
        let npix = width * height;
        if npix == 0 {
            return Err(GpuError::InvalidInput {
                reason: "consistency: the reference view has no pixels".to_owned(),
            });
        }
        let name = match variant {
            AccumulateVariant::FloatAtomic => "loss_consistency_atomic",
            AccumulateVariant::CompareAndSwap => "loss_consistency_cas",
        };
        let kernel = shaders::build(ctx, name)?;
        let mut buffers = Vec::new();
        for (name, floats, loc) in [
            ("consistency.terms", 2 * npix, MemoryLocation::DeviceOnly),
            ("consistency.sums", 2, MemoryLocation::Readback),
        ] {
            match ctx.create_buffer(name, (floats * 4) as u64, loc) {
                Ok(b) => buffers.push(b),
                Err(e) => {
                    ctx.destroy_kernel(kernel);
                    buffers.into_iter().for_each(|b| ctx.destroy_buffer(b));
                    return Err(e);
                }
            }
        }
        let sum = match GpuSum::new(ctx, ReduceVariant::best_for(ctx.capabilities()), npix) {
            Ok(s) => s,
            Err(e) => {
                ctx.destroy_kernel(kernel);
                buffers.into_iter().for_each(|b| ctx.destroy_buffer(b));
                return Err(e);
            }
        };
        let mut b = buffers.into_iter();
        let (Some(terms), Some(sums)) = (b.next(), b.next()) else {
            return Err(GpuError::Shader {
                name: name.to_owned(),
                reason: "buffer list incomplete".to_owned(),
            });
        };
        Ok(Self {
            kernel,
            sum,
            terms,
            sums,
            width,
            height,
        })
    }

    /// Records the term of `views` with `weight` (λc): adds `weight · dL/dΨ` to the upstream
    /// buffers (both, or view i's alone) and reduces the loss and valid count into the result
    /// slots.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        views: &ConsistencyViews<'_>,
        opt: &ConsistencyOptions,
        weight: f32,
    ) -> Result<(), GpuError> {
        let npix = self.width * self.height;
        let mut push = push_u32s(&[
            self.width as u32,
            self.height as u32,
            views.width_j as u32,
            views.height_j as u32,
        ]);
        for v in [
            opt.min_alpha as f32,
            opt.depth_rel_tol as f32,
            opt.near_m as f32,
            weight / npix as f32,
        ] {
            push.extend_from_slice(&v.to_le_bytes());
        }
        push.extend_from_slice(&u32::from(views.up_j.is_some()).to_le_bytes());
        rec.dispatch(
            &self.kernel,
            &[
                views.cam_i,
                views.cam_j,
                views.planes_i,
                views.planes_j,
                views.up_i,
                // Never written without gradient to view j (the kernel's `grad_j` is 0).
                views.up_j.unwrap_or(views.up_i),
                &self.terms,
            ],
            &push,
            [
                self.width.div_ceil(WG_2D) as u32,
                self.height.div_ceil(WG_2D) as u32,
                1,
            ],
        )?;
        rec.compute_barrier();
        for slot in 0..2 {
            self.sum
                .record(rec, &self.terms, slot * npix, npix, &self.sums, slot)?;
        }
        Ok(())
    }

    /// The loss (unweighted, as [`Consistency::loss`]) and valid-pixel count of the last
    /// recorded submission (2 floats: a small readback).
    pub fn values(&self, ctx: &GpuContext) -> Result<Consistency, GpuError> {
        Ok(self.values_from(&ctx.read::<f32>(&self.sums, 2)?))
    }

    /// The 2 sums [`Self::values`] reads (host-visible), for a caller that copies them into a
    /// buffer of its own to read several results at once.
    pub fn sums_buffer(&self) -> &GpuBuffer {
        &self.sums
    }

    /// The term from the 2 floats of [`Self::sums_buffer`].
    pub fn values_from(&self, s: &[f32]) -> Consistency {
        let n = (self.width * self.height) as f64;
        Consistency {
            loss: f64::from(s.first().copied().unwrap_or(f32::NAN)) / n,
            valid_px: s.get(1).copied().unwrap_or(0.0).round().max(0.0) as usize,
        }
    }

    pub fn destroy(self, ctx: &GpuContext) {
        ctx.destroy_kernel(self.kernel);
        self.sum.destroy(ctx);
        ctx.destroy_buffer(self.terms);
        ctx.destroy_buffer(self.sums);
    }
}
