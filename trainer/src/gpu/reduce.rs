//! Parallel float sums on the GPU: the first kernel of the trainer's shader pipeline, proving
//! GLSL → glslc → SPIR-V → ash end to end, and the pattern every later kernel follows for
//! device differences: two variants with one interface, chosen at run time from
//! [`Capabilities`] (subgroup arithmetic where the driver has it, shared memory otherwise).
//!
//! [`GpuSum`] records sums of buffer ranges into result slots without leaving the GPU (loss
//! values are reduced on the device and read back only when someone looks at them);
//! [`sum_f32`] is the one-shot convenience over host data.

use super::context::{
    Capabilities, ComputeKernel, GpuBuffer, GpuContext, MemoryLocation, Recorder,
};
use super::error::GpuError;
use super::shaders::{self, push_u32s};

/// Inputs one workgroup reduces (WG × ITEMS in the shaders).
pub const PER_GROUP: usize = 256 * 8;

/// Which kernel performs each pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReduceVariant {
    /// `subgroupAdd` within subgroups, shared memory across them.
    Subgroup,
    /// Shared-memory tree only: runs on any Vulkan 1.2 device.
    SharedMemory,
}

impl ReduceVariant {
    /// The fastest variant the device supports.
    pub fn best_for(caps: Capabilities) -> Self {
        if caps.subgroup_arithmetic {
            Self::Subgroup
        } else {
            Self::SharedMemory
        }
    }

    fn kernel_name(self) -> &'static str {
        match self {
            Self::Subgroup => "reduce_subgroup",
            Self::SharedMemory => "reduce_shared",
        }
    }
}

/// A reusable GPU sum of up to `max_count` floats per call (pairwise tree order: the rounding
/// error grows like log n, not n).
#[derive(Debug)]
pub struct GpuSum {
    kernel: ComputeKernel,
    /// Ping-pong scratch for the partial sums of multi-pass reductions.
    scratch: [GpuBuffer; 2],
    max_count: usize,
}

impl GpuSum {
    pub fn new(
        ctx: &GpuContext,
        variant: ReduceVariant,
        max_count: usize,
    ) -> Result<Self, GpuError> {
        let kernel = shaders::build(ctx, variant.kernel_name())?;
        let partials = max_count.div_ceil(PER_GROUP).max(1) as u64 * 4;
        let a = ctx.create_buffer("sum.scratch0", partials, MemoryLocation::DeviceOnly);
        let b = a.and_then(|a| {
            match ctx.create_buffer("sum.scratch1", partials, MemoryLocation::DeviceOnly) {
                Ok(b) => Ok((a, b)),
                Err(e) => {
                    ctx.destroy_buffer(a);
                    Err(e)
                }
            }
        });
        match b {
            Ok((a, b)) => Ok(Self {
                kernel,
                scratch: [a, b],
                max_count,
            }),
            Err(e) => {
                ctx.destroy_kernel(kernel);
                Err(e)
            }
        }
    }

    /// Records `dst[dst_index] = Σ src[src_offset .. src_offset + count]`.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        src: &GpuBuffer,
        src_offset: usize,
        count: usize,
        dst: &GpuBuffer,
        dst_index: usize,
    ) -> Result<(), GpuError> {
        if count > self.max_count {
            return Err(GpuError::BufferRange {
                name: src.name().to_owned(),
                requested_bytes: (count * 4) as u64,
                capacity_bytes: (self.max_count * 4) as u64,
            });
        }
        let mut input = src;
        let mut in_offset = src_offset;
        let mut remaining = count;
        let mut pass = 0usize;
        loop {
            let groups = remaining.div_ceil(PER_GROUP).max(1);
            let last = groups == 1;
            let (output, out_offset) = if last {
                (dst, dst_index)
            } else {
                (&self.scratch[pass % 2], 0)
            };
            let push = push_u32s(&[remaining as u32, in_offset as u32, out_offset as u32]);
            rec.dispatch(&self.kernel, &[input, output], &push, [groups as u32, 1, 1])?;
            rec.compute_barrier();
            if last {
                return Ok(());
            }
            input = output;
            in_offset = 0;
            remaining = groups;
            pass += 1;
        }
    }

    pub fn destroy(self, ctx: &GpuContext) {
        ctx.destroy_kernel(self.kernel);
        let [a, b] = self.scratch;
        ctx.destroy_buffer(a);
        ctx.destroy_buffer(b);
    }
}

/// Sums `values` on the GPU in f32.
pub fn sum_f32(ctx: &GpuContext, values: &[f32], variant: ReduceVariant) -> Result<f32, GpuError> {
    if values.is_empty() {
        return Ok(0.0);
    }
    let sum = GpuSum::new(ctx, variant, values.len())?;
    let result = (|| {
        let input = ctx.upload("sum.values", values)?;
        let out = match ctx.create_buffer("sum.result", 4, MemoryLocation::Readback) {
            Ok(b) => b,
            Err(e) => {
                ctx.destroy_buffer(input);
                return Err(e);
            }
        };
        let total = ctx
            .submit(|rec| sum.record(rec, &input, 0, values.len(), &out, 0))
            .and_then(|()| ctx.read::<f32>(&out, 1));
        ctx.destroy_buffer(input);
        ctx.destroy_buffer(out);
        total?
            .first()
            .copied()
            .ok_or_else(|| GpuError::BufferRange {
                name: "sum.result".to_owned(),
                requested_bytes: 4,
                capacity_bytes: 0,
            })
    })();
    sum.destroy(ctx);
    result
}
