//! The rasteriser's per-variant kernels: projection, forward pass, backward walk and its
//! per-primitive finish, in two sets with one interface each — thermal image and G-buffers,
//! and the same with the SH colour (`*_rgb`: the shaders compiled with `USE_COLOUR`). A run
//! without colour builds and runs only the first set, whose SPIR-V does not change with the
//! colour branch; the colour set is built when a view with colour is first rendered.

use crate::gpu::accumulate::AccumulateVariant;
use crate::gpu::context::{ComputeKernel, GpuContext};
use crate::gpu::error::GpuError;
use crate::gpu::shaders;

/// The kernels of one variant (thermal, or with the SH colour).
#[derive(Debug)]
pub(super) struct StageKernels {
    pub(super) project: ComputeKernel,
    pub(super) forward: ComputeKernel,
    pub(super) backward: ComputeKernel,
    pub(super) finish: ComputeKernel,
}

impl StageKernels {
    /// Builds the kernels of the thermal (`colour` false) or the colour variant, with gradient
    /// accumulation by `variant`, summed over the subgroup first when `subgroup_reduce`.
    pub(super) fn build(
        ctx: &GpuContext,
        variant: AccumulateVariant,
        subgroup_reduce: bool,
        colour: bool,
    ) -> Result<Self, GpuError> {
        let backward = match (variant, subgroup_reduce) {
            (AccumulateVariant::FloatAtomic, true) => "raster_backward_atomic_sg",
            (AccumulateVariant::FloatAtomic, false) => "raster_backward_atomic",
            (AccumulateVariant::CompareAndSwap, true) => "raster_backward_cas_sg",
            (AccumulateVariant::CompareAndSwap, false) => "raster_backward_cas",
        };
        let suffix = if colour { "_rgb" } else { "" };
        let names = [
            "raster_project",
            "raster_forward",
            backward,
            "raster_backward_finish",
        ]
        .map(|n| format!("{n}{suffix}"));
        let mut built = build_all(ctx, &names)?.into_iter();
        match (built.next(), built.next(), built.next(), built.next()) {
            (Some(project), Some(forward), Some(backward), Some(finish)) => Ok(Self {
                project,
                forward,
                backward,
                finish,
            }),
            _ => Err(GpuError::Shader {
                name: "raster".to_owned(),
                reason: "kernel list incomplete".to_owned(),
            }),
        }
    }

    pub(super) fn destroy(self, ctx: &GpuContext) {
        for k in [self.project, self.forward, self.backward, self.finish] {
            ctx.destroy_kernel(k);
        }
    }
}

/// Builds the kernels `names`, in order; on an error, releases those already built.
pub(super) fn build_all<S: AsRef<str>>(
    ctx: &GpuContext,
    names: &[S],
) -> Result<Vec<ComputeKernel>, GpuError> {
    let mut built = Vec::with_capacity(names.len());
    for name in names {
        match shaders::build(ctx, name.as_ref()) {
            Ok(k) => built.push(k),
            Err(e) => {
                for k in built {
                    ctx.destroy_kernel(k);
                }
                return Err(e);
            }
        }
    }
    Ok(built)
}
