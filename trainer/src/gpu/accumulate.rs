//! Scatter-add of float contributions into bins: how the backward rasteriser accumulates
//! per-primitive gradients from many pixels. Two kernels, one interface, chosen at run time:
//! `atomicAdd(float)` where the device has it, a compare-and-swap loop on the bits otherwise
//! (Raspberry Pi 5's driver has no float atomics).

use super::context::{Capabilities, ComputeKernel, GpuBuffer, GpuContext, Recorder};
use super::error::GpuError;
use super::shaders::{self, push_u32s};

const WG: usize = 256;

/// Which accumulation kernel runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AccumulateVariant {
    /// `atomicAdd(float)` on storage buffers.
    FloatAtomic,
    /// `atomicCompSwap` loop on the float's bits: core Vulkan, slower under contention.
    CompareAndSwap,
}

impl AccumulateVariant {
    /// Float atomics where enabled on the context, else the CAS loop.
    pub fn best_for(caps: Capabilities) -> Self {
        if caps.float_atomic_add {
            Self::FloatAtomic
        } else {
            Self::CompareAndSwap
        }
    }
}

/// A built accumulation kernel.
#[derive(Debug)]
pub struct GpuAccumulate {
    kernel: ComputeKernel,
    variant: AccumulateVariant,
}

impl GpuAccumulate {
    /// Builds `variant`; asking for `FloatAtomic` on a context without float atomics is a typed
    /// `MissingFeature` error.
    pub fn new(ctx: &GpuContext, variant: AccumulateVariant) -> Result<Self, GpuError> {
        let name = match variant {
            AccumulateVariant::FloatAtomic => "accumulate_atomic",
            AccumulateVariant::CompareAndSwap => "accumulate_cas",
        };
        Ok(Self {
            kernel: shaders::build(ctx, name)?,
            variant,
        })
    }

    pub fn variant(&self) -> AccumulateVariant {
        self.variant
    }

    /// Records `accum[bin_of[i]] += contribution[i]` for `i < count`.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bin_of: &GpuBuffer,
        contribution: &GpuBuffer,
        accum: &GpuBuffer,
        count: usize,
    ) -> Result<(), GpuError> {
        if count == 0 {
            return Ok(());
        }
        rec.dispatch(
            &self.kernel,
            &[bin_of, contribution, accum],
            &push_u32s(&[count as u32]),
            [count.div_ceil(WG) as u32, 1, 1],
        )?;
        rec.compute_barrier();
        Ok(())
    }

    pub fn destroy(self, ctx: &GpuContext) {
        ctx.destroy_kernel(self.kernel);
    }
}
