//! The single-view loss of S³-TIR on the GPU (`crate::loss::view_loss` as kernels):
//! `(1 − λ)·L1 + λ·(1 − SSIM)` on the thermal plane, `λs·L1(Ψ_high)` and `λg·TV(Ψ_β)`, and their
//! gradients written straight into the backward rasteriser's upstream planes. The loss values are
//! reduced on the GPU into four result slots (L1, SSIM, sparsity, TV means × pixel count) and
//! read back only when asked for. With a view response (`crate::loss::response`) the thermal
//! plane is seen through it and two more slots hold `dL/dgain` and `dL/doffset`.
//!
//! Kernels: `loss_ssim_prepare` (x, y, x², y², xy) → `loss_blur` ×2 (separable 11×11 Gaussian)
//! → `loss_ssim_map` (SSIM and its three backward maps) → `loss_blur` ×2 (the blur is
//! self-adjoint) → `loss_grad` (every upstream plane and the per-pixel terms) → 4 sums (6 with
//! a response).
//!
//! The multi-view consistency term is [`super::consistency`].

use super::context::{ComputeKernel, GpuBuffer, GpuContext, MemoryLocation, Recorder};
use super::error::GpuError;
use super::reduce::{GpuSum, ReduceVariant};
use super::shaders::{self, push_u32s};
use crate::loss::LossWeights;
use crate::loss::response::{ResponseGrad, ViewResponse};

/// Result slots: the four loss sums, then the response's two gradient sums.
pub const LOSS_SLOTS: usize = 6;

const WG_1D: usize = 256;
const WG_2D: usize = 16;

/// Loss values of one view (unweighted terms, as `crate::loss::ViewLoss`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpuViewLossValues {
    pub l1: f64,
    pub ssim: f64,
    pub sparse: f64,
    pub smooth: f64,
    /// `dL/dgain`, `dL/doffset` of the view's response (`None`: recorded without one).
    pub response: Option<ResponseGrad>,
}

impl GpuViewLossValues {
    /// `(1 − λ)·l1 + λ·(1 − ssim) + λs·sparse + λg·smooth`.
    pub fn total(&self, w: &LossWeights) -> f64 {
        (1.0 - w.lambda_dssim) * self.l1
            + w.lambda_dssim * (1.0 - self.ssim)
            + w.lambda_sparse * self.sparse
            + w.lambda_smooth * self.smooth
    }
}

/// Kernels and scratch buffers for views of one size.
#[derive(Debug)]
pub struct GpuViewLoss {
    prepare: ComputeKernel,
    blur: ComputeKernel,
    map: ComputeKernel,
    grad: ComputeKernel,
    sum: GpuSum,
    /// 5 statistics planes and their blur (ping-pong), 3 backward maps and their blur.
    stats: [GpuBuffer; 2],
    maps: [GpuBuffer; 2],
    /// Per-pixel terms (6 planes) and the [`LOSS_SLOTS`] sums.
    terms: GpuBuffer,
    sums: GpuBuffer,
    width: usize,
    height: usize,
}

impl GpuViewLoss {
    pub fn new(ctx: &GpuContext, width: usize, height: usize) -> Result<Self, GpuError> {
        let npix = width * height;
        let mut kernels = Vec::new();
        for name in [
            "loss_ssim_prepare",
            "loss_blur",
            "loss_ssim_map",
            "loss_grad",
        ] {
            match shaders::build(ctx, name) {
                Ok(k) => kernels.push(k),
                Err(e) => {
                    kernels.into_iter().for_each(|k| ctx.destroy_kernel(k));
                    return Err(e);
                }
            }
        }
        let mut buffers = Vec::new();
        let specs = [
            ("loss.stats0", 5 * npix, MemoryLocation::DeviceOnly),
            ("loss.stats1", 5 * npix, MemoryLocation::DeviceOnly),
            ("loss.maps0", 3 * npix, MemoryLocation::DeviceOnly),
            ("loss.maps1", 3 * npix, MemoryLocation::DeviceOnly),
            ("loss.terms", LOSS_SLOTS * npix, MemoryLocation::DeviceOnly),
            ("loss.sums", LOSS_SLOTS, MemoryLocation::Readback),
        ];
        for (name, floats, loc) in specs {
            match ctx.create_buffer(name, (floats * 4) as u64, loc) {
                Ok(b) => buffers.push(b),
                Err(e) => {
                    kernels.into_iter().for_each(|k| ctx.destroy_kernel(k));
                    buffers.into_iter().for_each(|b| ctx.destroy_buffer(b));
                    return Err(e);
                }
            }
        }
        let sum = match GpuSum::new(ctx, ReduceVariant::best_for(ctx.capabilities()), npix) {
            Ok(s) => s,
            Err(e) => {
                kernels.into_iter().for_each(|k| ctx.destroy_kernel(k));
                buffers.into_iter().for_each(|b| ctx.destroy_buffer(b));
                return Err(e);
            }
        };
        let mut k = kernels.into_iter();
        let mut b = buffers.into_iter();
        let incomplete = || GpuError::Shader {
            name: "loss".to_owned(),
            reason: "kernel or buffer list incomplete".to_owned(),
        };
        let (Some(prepare), Some(blur), Some(map), Some(grad)) =
            (k.next(), k.next(), k.next(), k.next())
        else {
            return Err(incomplete());
        };
        let (Some(s0), Some(s1), Some(m0), Some(m1), Some(terms), Some(sums)) =
            (b.next(), b.next(), b.next(), b.next(), b.next(), b.next())
        else {
            return Err(incomplete());
        };
        Ok(Self {
            prepare,
            blur,
            map,
            grad,
            sum,
            stats: [s0, s1],
            maps: [m0, m1],
            terms,
            sums,
            width,
            height,
        })
    }

    /// Records the loss of `rendered` (the rasteriser's 6 planes) against `target` (one plane),
    /// the thermal plane seen through `response` when given: writes all 6 `upstream` planes
    /// (w.r.t. the rendered values) and the four sums, and with a response its two gradient
    /// sums.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        rendered: &GpuBuffer,
        target: &GpuBuffer,
        upstream: &GpuBuffer,
        weights: &LossWeights,
        response: Option<&ViewResponse>,
    ) -> Result<(), GpuError> {
        let (w, h) = (self.width, self.height);
        let npix = w * h;
        let groups_1d = [npix.div_ceil(WG_1D) as u32, 1, 1];
        let groups_2d = [w.div_ceil(WG_2D) as u32, h.div_ceil(WG_2D) as u32, 1];
        let n = push_u32s(&[npix as u32]);
        let resp = response.copied().unwrap_or(ViewResponse::identity(0.0));
        let mut resp_push = Vec::with_capacity(12);
        for v in [resp.gain, resp.offset, resp.pivot] {
            resp_push.extend_from_slice(&(v as f32).to_le_bytes());
        }
        let mut prepare_push = n.clone();
        prepare_push.extend_from_slice(&resp_push);
        rec.dispatch(
            &self.prepare,
            &[rendered, target, &self.stats[0]],
            &prepare_push,
            groups_1d,
        )?;
        rec.compute_barrier();
        self.record_blur(rec, &self.stats, 5, groups_2d)?;
        rec.dispatch(
            &self.map,
            &[&self.stats[0], &self.maps[0], &self.terms],
            &n,
            groups_1d,
        )?;
        rec.compute_barrier();
        self.record_blur(rec, &self.maps, 3, groups_2d)?;
        let mut push = push_u32s(&[w as u32, h as u32]);
        for v in [
            weights.lambda_dssim,
            weights.lambda_sparse,
            weights.lambda_smooth,
        ] {
            push.extend_from_slice(&(v as f32).to_le_bytes());
        }
        push.extend_from_slice(&resp_push);
        rec.dispatch(
            &self.grad,
            &[rendered, target, &self.maps[0], upstream, &self.terms],
            &push,
            groups_2d,
        )?;
        rec.compute_barrier();
        let slots = if response.is_some() { LOSS_SLOTS } else { 4 };
        for slot in 0..slots {
            self.sum
                .record(rec, &self.terms, slot * npix, npix, &self.sums, slot)?;
        }
        Ok(())
    }

    /// Blurs `pair[0]` along x into `pair[1]`, then along y back into `pair[0]`.
    fn record_blur(
        &self,
        rec: &mut Recorder<'_>,
        pair: &[GpuBuffer; 2],
        channels: u32,
        groups: [u32; 3],
    ) -> Result<(), GpuError> {
        let (w, h) = (self.width as u32, self.height as u32);
        rec.dispatch(
            &self.blur,
            &[&pair[0], &pair[1]],
            &push_u32s(&[w, h, channels, 0]),
            groups,
        )?;
        rec.compute_barrier();
        rec.dispatch(
            &self.blur,
            &[&pair[1], &pair[0]],
            &push_u32s(&[w, h, channels, 1]),
            groups,
        )?;
        rec.compute_barrier();
        Ok(())
    }

    /// Reads the loss values of the last recorded submission ([`LOSS_SLOTS`] floats: a small
    /// readback); `response`: whether it was recorded with one.
    pub fn values(&self, ctx: &GpuContext, response: bool) -> Result<GpuViewLossValues, GpuError> {
        Ok(self.values_from(&ctx.read::<f32>(&self.sums, LOSS_SLOTS)?, response))
    }

    /// The [`LOSS_SLOTS`] sums [`Self::values`] reads (host-visible), for a caller that copies
    /// them into a buffer of its own to read several results at once.
    pub fn sums_buffer(&self) -> &GpuBuffer {
        &self.sums
    }

    /// The values from the [`LOSS_SLOTS`] floats of [`Self::sums_buffer`].
    pub fn values_from(&self, s: &[f32], response: bool) -> GpuViewLossValues {
        let n = (self.width * self.height) as f64;
        let at = |i: usize| f64::from(s.get(i).copied().unwrap_or(f32::NAN));
        let mean = |i: usize| at(i) / n;
        GpuViewLossValues {
            l1: mean(0),
            ssim: mean(1),
            sparse: mean(2),
            smooth: mean(3),
            response: response.then(|| ResponseGrad {
                gain: at(4),
                offset: at(5),
            }),
        }
    }

    pub fn destroy(self, ctx: &GpuContext) {
        for k in [self.prepare, self.blur, self.map, self.grad] {
            ctx.destroy_kernel(k);
        }
        self.sum.destroy(ctx);
        let [s0, s1] = self.stats;
        let [m0, m1] = self.maps;
        for b in [s0, s1, m0, m1, self.terms, self.sums] {
            ctx.destroy_buffer(b);
        }
    }
}
