//! Compute kernels: a pipeline built from SPIR-V with its descriptor-set layout (bindings
//! 0.. in set 0, storage or texel buffers) and push-constant block, checked against the
//! device's per-stage storage-buffer limit, and its release.

use ash::vk;

use super::GpuContext;
use crate::gpu::error::{GpuError, vk_err};

/// How a kernel binding is declared (set 0, bindings 0.. in order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Binding {
    /// A `buffer` block: a storage buffer.
    Storage,
    /// A `samplerBuffer` / `usamplerBuffer` read with `texelFetch`: a uniform texel buffer
    /// viewing the whole buffer in `TexelFormat`. Read-only data that a kernel fetches at
    /// scattered (per-invocation) positions: software Vulkan (lavapipe's gallivm) fetches
    /// texels with vector gathers, while it loads storage buffers one invocation at a time.
    Texel(TexelFormat),
}

/// Formats of texel-buffer bindings (both must be supported for uniform texel buffers by every
/// Vulkan device).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TexelFormat {
    /// `vec4` texels (`samplerBuffer`).
    Rgba32Float,
    /// `uint` texels (`usamplerBuffer`).
    R32Uint,
}

impl TexelFormat {
    pub(super) fn vk(self) -> vk::Format {
        match self {
            Self::Rgba32Float => vk::Format::R32G32B32A32_SFLOAT,
            Self::R32Uint => vk::Format::R32_UINT,
        }
    }

    /// Bytes per texel.
    pub fn bytes(self) -> u64 {
        match self {
            Self::Rgba32Float => 16,
            Self::R32Uint => 4,
        }
    }
}

/// A compute pipeline with its interface: `bindings` 0.. in set 0 and a push constant block of
/// `push_constant_bytes`. Release with [`GpuContext::destroy_kernel`].
#[derive(Debug)]
pub struct ComputeKernel {
    pub(super) name: String,
    pub(super) pipeline: vk::Pipeline,
    pub(super) layout: vk::PipelineLayout,
    pub(super) set_layout: vk::DescriptorSetLayout,
    pub(super) bindings: Vec<Binding>,
    pub(super) push_constant_bytes: u32,
}

impl ComputeKernel {
    pub fn name(&self) -> &str {
        &self.name
    }
}

impl GpuContext {
    /// Creates a compute pipeline from SPIR-V words with `bindings` 0.. in set 0 and a
    /// push-constant block of `push_constant_bytes`.
    pub fn create_kernel(
        &self,
        name: &str,
        spirv: &[u32],
        bindings: &[Binding],
        push_constant_bytes: u32,
    ) -> Result<ComputeKernel, GpuError> {
        let limit = self.report.max_per_stage_storage_buffers;
        let storage_buffers = bindings.iter().filter(|b| **b == Binding::Storage).count() as u32;
        if storage_buffers > limit {
            return Err(GpuError::LimitTooSmall {
                device: self.report.name.clone(),
                limit: "maxPerStageDescriptorStorageBuffers",
                required: u64::from(storage_buffers),
                actual: u64::from(limit),
            });
        }
        let d = &self.device;
        let layout_bindings: Vec<_> = bindings
            .iter()
            .enumerate()
            .map(|(b, kind)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b as u32)
                    .descriptor_type(descriptor_type(*kind))
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        // SAFETY (whole block): valid device; every object is destroyed on the error paths
        // below or later by destroy_kernel.
        unsafe {
            let set_layout = d
                .create_descriptor_set_layout(
                    &vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings),
                    None,
                )
                .map_err(vk_err("vkCreateDescriptorSetLayout"))?;
            let ranges = [vk::PushConstantRange::default()
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
                .offset(0)
                .size(push_constant_bytes)];
            let set_layouts = [set_layout];
            let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
            if push_constant_bytes > 0 {
                layout_info = layout_info.push_constant_ranges(&ranges);
            }
            let layout = match d.create_pipeline_layout(&layout_info, None) {
                Ok(l) => l,
                Err(result) => {
                    d.destroy_descriptor_set_layout(set_layout, None);
                    return Err(GpuError::Vk {
                        call: "vkCreatePipelineLayout",
                        result,
                    });
                }
            };
            let module = match d
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(spirv), None)
            {
                Ok(m) => m,
                Err(result) => {
                    d.destroy_pipeline_layout(layout, None);
                    d.destroy_descriptor_set_layout(set_layout, None);
                    return Err(GpuError::ShaderBuild {
                        name: name.to_owned(),
                        call: "vkCreateShaderModule",
                        source: result,
                    });
                }
            };
            let stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(module)
                .name(c"main");
            let info = [vk::ComputePipelineCreateInfo::default()
                .stage(stage)
                .layout(layout)];
            let pipelines = d.create_compute_pipelines(vk::PipelineCache::null(), &info, None);
            d.destroy_shader_module(module, None);
            let pipeline = match pipelines {
                Ok(p) => p.first().copied().ok_or(vk::Result::ERROR_UNKNOWN),
                Err((_, result)) => Err(result),
            };
            match pipeline {
                Ok(pipeline) => Ok(ComputeKernel {
                    name: name.to_owned(),
                    pipeline,
                    layout,
                    set_layout,
                    bindings: bindings.to_vec(),
                    push_constant_bytes,
                }),
                Err(result) => {
                    d.destroy_pipeline_layout(layout, None);
                    d.destroy_descriptor_set_layout(set_layout, None);
                    Err(GpuError::ShaderBuild {
                        name: name.to_owned(),
                        call: "vkCreateComputePipelines",
                        source: result,
                    })
                }
            }
        }
    }

    /// Releases a kernel (no pending work may use it).
    pub fn destroy_kernel(&self, kernel: ComputeKernel) {
        // SAFETY: objects of this device, not in use.
        unsafe {
            self.device.destroy_pipeline(kernel.pipeline, None);
            self.device.destroy_pipeline_layout(kernel.layout, None);
            self.device
                .destroy_descriptor_set_layout(kernel.set_layout, None);
        }
    }
}

/// The descriptor type a binding is declared with.
pub(super) fn descriptor_type(binding: Binding) -> vk::DescriptorType {
    match binding {
        Binding::Storage => vk::DescriptorType::STORAGE_BUFFER,
        Binding::Texel(_) => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
    }
}
