//! The compute kernels of `trainer/shaders/`, compiled to SPIR-V by glslc in build.rs, and the
//! interface each one has. A test checks that every compiled shader has an entry here and
//! builds a pipeline from it on a real driver, so a broken shader cannot slip through.

use super::context::{Binding, Capabilities, ComputeKernel, GpuContext, TexelFormat};
use super::error::GpuError;

/// The optimiser kernel's push constants: 4 words of sizes and gate, 9 step sizes, 4 Adam and
/// clamp constants, 12 for the densification statistic's camera (within Vulkan's guaranteed
/// 128 bytes). Declared with the kernel table, which every kernel's module reads (the
/// optimiser fills them), so the table imports no kernel module.
pub(crate) const ADAM_PUSH_BYTES: u32 = 4 * (4 + 9 + 4 + 12 + 1);

include!(concat!(env!("OUT_DIR"), "/shaders.rs"));

/// The host-side interface of a kernel. Shared memory is not listed: every kernel stays within
/// the 16 KiB Vulkan guarantees (`maxComputeSharedMemorySize`; the largest, the subgroup
/// backward rasteriser, uses 14 KiB).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KernelSpec {
    /// File stem in `trainer/shaders/` (`reduce_shared` for `reduce_shared.comp`).
    pub name: &'static str,
    /// Bindings 0.. of set 0: storage buffers, except those listed in `texel`.
    pub bindings: u32,
    /// The bindings that are texel buffers (`samplerBuffer`/`usamplerBuffer`), with their format.
    pub texel: &'static [(u32, TexelFormat)],
    /// Size of the push-constant block.
    pub push_constant_bytes: u32,
    /// Needs subgroup arithmetic (subgroupAdd …) in compute.
    pub needs_subgroup_arithmetic: bool,
    /// Needs `atomicAdd(float)` on storage buffers.
    pub needs_float_atomic_add: bool,
}

/// The rasterisers' texel bindings: primitive views, band views (RGBA32F) and the sorted
/// primitive list (R32UI); see raster_common.glsl.
const RASTER_TEXELS: &[(u32, TexelFormat)] = &[
    (1, TexelFormat::Rgba32Float),
    (2, TexelFormat::Rgba32Float),
    (3, TexelFormat::R32Uint),
];

/// The texel bindings of `raster_forward_rgb`: [`RASTER_TEXELS`] and the primitives' colours
/// (RGBA32F) at binding 6.
const RASTER_FORWARD_RGB_TEXELS: &[(u32, TexelFormat)] = &[
    (1, TexelFormat::Rgba32Float),
    (2, TexelFormat::Rgba32Float),
    (3, TexelFormat::R32Uint),
    (6, TexelFormat::Rgba32Float),
];

/// The texel bindings of `raster_backward_*_rgb`: [`RASTER_TEXELS`] and the primitives' colours
/// (RGBA32F) at binding 8.
const RASTER_BACKWARD_RGB_TEXELS: &[(u32, TexelFormat)] = &[
    (1, TexelFormat::Rgba32Float),
    (2, TexelFormat::Rgba32Float),
    (3, TexelFormat::R32Uint),
    (8, TexelFormat::Rgba32Float),
];

/// Every kernel's interface. The `*_rgb` kernels are the rasteriser's with the SH colour
/// (`USE_COLOUR`), built only for runs with colour.
pub const KERNELS: &[KernelSpec] = &[
    KernelSpec {
        name: "reduce_shared",
        bindings: 2,
        texel: &[],
        push_constant_bytes: 12,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "reduce_subgroup",
        bindings: 2,
        texel: &[],
        push_constant_bytes: 12,
        needs_subgroup_arithmetic: true,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "scan_blocks",
        bindings: 2,
        texel: &[],
        push_constant_bytes: 4,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "scan_add",
        bindings: 2,
        texel: &[],
        push_constant_bytes: 4,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "radix_count",
        bindings: 3,
        texel: &[],
        push_constant_bytes: 16,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "radix_scatter",
        bindings: 6,
        texel: &[],
        push_constant_bytes: 16,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "accumulate_atomic",
        bindings: 3,
        texel: &[],
        push_constant_bytes: 4,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: true,
    },
    KernelSpec {
        name: "accumulate_cas",
        bindings: 3,
        texel: &[],
        push_constant_bytes: 4,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_project",
        bindings: 6,
        texel: &[],
        push_constant_bytes: 16,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_project_rgb",
        bindings: 7,
        texel: &[],
        push_constant_bytes: 20,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_emit",
        bindings: 4,
        texel: &[],
        push_constant_bytes: 12,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_ranges",
        bindings: 3,
        texel: &[],
        push_constant_bytes: 4,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_forward",
        bindings: 6,
        texel: RASTER_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_forward_rgb",
        bindings: 7,
        texel: RASTER_FORWARD_RGB_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_backward_atomic",
        bindings: 8,
        texel: RASTER_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: true,
    },
    KernelSpec {
        name: "raster_backward_cas",
        bindings: 8,
        texel: RASTER_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_backward_atomic_sg",
        bindings: 8,
        texel: RASTER_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: true,
        needs_float_atomic_add: true,
    },
    KernelSpec {
        name: "raster_backward_cas_sg",
        bindings: 8,
        texel: RASTER_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: true,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_backward_atomic_rgb",
        bindings: 9,
        texel: RASTER_BACKWARD_RGB_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: true,
    },
    KernelSpec {
        name: "raster_backward_cas_rgb",
        bindings: 9,
        texel: RASTER_BACKWARD_RGB_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_backward_atomic_sg_rgb",
        bindings: 9,
        texel: RASTER_BACKWARD_RGB_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: true,
        needs_float_atomic_add: true,
    },
    KernelSpec {
        name: "raster_backward_cas_sg_rgb",
        bindings: 9,
        texel: RASTER_BACKWARD_RGB_TEXELS,
        push_constant_bytes: 24,
        needs_subgroup_arithmetic: true,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "adam",
        bindings: 9,
        texel: &[],
        push_constant_bytes: ADAM_PUSH_BYTES,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_backward_finish",
        bindings: 5,
        texel: &[],
        push_constant_bytes: 8,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "raster_backward_finish_rgb",
        bindings: 5,
        texel: &[],
        push_constant_bytes: 12,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "loss_blur",
        bindings: 2,
        texel: &[],
        push_constant_bytes: 16,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "loss_ssim_prepare",
        bindings: 3,
        texel: &[],
        push_constant_bytes: 16,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "loss_ssim_map",
        bindings: 3,
        texel: &[],
        push_constant_bytes: 4,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "loss_grad",
        bindings: 5,
        texel: &[],
        push_constant_bytes: 32,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
    KernelSpec {
        name: "loss_consistency_atomic",
        bindings: 7,
        texel: &[],
        push_constant_bytes: 36,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: true,
    },
    KernelSpec {
        name: "loss_consistency_cas",
        bindings: 7,
        texel: &[],
        push_constant_bytes: 36,
        needs_subgroup_arithmetic: false,
        needs_float_atomic_add: false,
    },
];

/// Push constants as the little-endian bytes of consecutive `u32` fields (std430 `uint`s).
pub fn push_u32s(fields: &[u32]) -> Vec<u8> {
    fields.iter().flat_map(|f| f.to_le_bytes()).collect()
}

/// The interface of kernel `name`.
pub fn spec(name: &str) -> Result<&'static KernelSpec, GpuError> {
    KERNELS
        .iter()
        .find(|k| k.name == name)
        .ok_or_else(|| GpuError::Shader {
            name: name.to_owned(),
            reason: "no such kernel in trainer/shaders".to_owned(),
        })
}

/// SPIR-V words of kernel `name`.
pub fn spirv(name: &str) -> Result<Vec<u32>, GpuError> {
    let bytes = SHADERS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, b)| *b)
        .ok_or_else(|| GpuError::Shader {
            name: name.to_owned(),
            reason: "not compiled into this build".to_owned(),
        })?;
    ash::util::read_spv(&mut std::io::Cursor::new(bytes)).map_err(|source| {
        GpuError::MalformedSpirv {
            name: name.to_owned(),
            source,
        }
    })
}

/// Whether a device with `caps` can run kernel `spec`; `Err` names the missing feature.
pub fn check_supported(
    spec: &KernelSpec,
    caps: Capabilities,
    device: &str,
) -> Result<(), GpuError> {
    let missing = |feature: &str| GpuError::MissingFeature {
        device: device.to_owned(),
        feature: format!("{feature} (needed by kernel {})", spec.name),
    };
    if spec.needs_subgroup_arithmetic && !caps.subgroup_arithmetic {
        return Err(missing("subgroup arithmetic in compute shaders"));
    }
    if spec.needs_float_atomic_add && !caps.float_atomic_add {
        return Err(missing("shaderBufferFloat32AtomicAdd"));
    }
    Ok(())
}

/// Builds the pipeline of kernel `name` on `ctx`, after checking the device supports it.
pub fn build(ctx: &GpuContext, name: &str) -> Result<ComputeKernel, GpuError> {
    let spec = spec(name)?;
    check_supported(spec, ctx.capabilities(), &ctx.report().name)?;
    let bindings: Vec<Binding> = (0..spec.bindings)
        .map(|b| {
            spec.texel
                .iter()
                .find(|(at, _)| *at == b)
                .map_or(Binding::Storage, |(_, format)| Binding::Texel(*format))
        })
        .collect();
    ctx.create_kernel(name, &spirv(name)?, &bindings, spec.push_constant_bytes)
}
