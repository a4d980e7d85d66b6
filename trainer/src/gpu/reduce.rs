//! Parallel float sum on the GPU: the first kernel of the trainer's shader pipeline, proving
//! GLSL → glslc → SPIR-V → ash end to end, and the pattern every later kernel follows for
//! device differences: two variants with one interface, chosen at run time from
//! [`Capabilities`] (subgroup arithmetic where the driver has it, shared memory otherwise).

use super::context::{Capabilities, GpuContext, MemoryLocation};
use super::error::GpuError;
use super::shaders;

/// Inputs one workgroup reduces (WG × ITEMS in the shaders).
const PER_GROUP: usize = 256 * 8;

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

/// Sums `values` on the GPU in f32 (pairwise tree order: error grows like log n, not n).
pub fn sum_f32(ctx: &GpuContext, values: &[f32], variant: ReduceVariant) -> Result<f32, GpuError> {
    if values.is_empty() {
        return Ok(0.0);
    }
    let kernel = shaders::build(ctx, variant.kernel_name())?;
    let result = (|| {
        let a = ctx.upload("reduce.values", values)?;
        let partials = values.len().div_ceil(PER_GROUP);
        let b = ctx.create_buffer(
            "reduce.partials",
            (partials * 4) as u64,
            MemoryLocation::Readback,
        );
        let b = match b {
            Ok(b) => b,
            Err(e) => {
                ctx.destroy_buffer(a);
                return Err(e);
            }
        };
        // Passes alternate a → b → a …; the count shrinks by PER_GROUP each pass.
        let mut passes = Vec::new();
        let mut count = values.len();
        while count > 1 {
            passes.push(count);
            count = count.div_ceil(PER_GROUP);
        }
        let submitted = ctx.submit(|rec| {
            for (i, &count) in passes.iter().enumerate() {
                let (src, dst) = if i % 2 == 0 { (&a, &b) } else { (&b, &a) };
                let groups = count.div_ceil(PER_GROUP) as u32;
                rec.dispatch(
                    &kernel,
                    &[src, dst],
                    &(count as u32).to_le_bytes(),
                    [groups, 1, 1],
                )?;
                rec.compute_barrier();
            }
            Ok(())
        });
        // The total sits at index 0 of the last pass's destination (or of `a` with one value).
        let total = submitted.and_then(|()| {
            let last = if passes.len() % 2 == 1 { &b } else { &a };
            ctx.read::<f32>(last, 1)
        });
        ctx.destroy_buffer(a);
        ctx.destroy_buffer(b);
        total?
            .first()
            .copied()
            .ok_or_else(|| GpuError::BufferRange {
                name: "reduce.partials".to_owned(),
                requested_bytes: 4,
                capacity_bytes: 0,
            })
    })();
    ctx.destroy_kernel(kernel);
    result
}
