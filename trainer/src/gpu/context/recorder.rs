//! Recording into one submission's command buffer: dispatches checked against their
//! kernel's interface (descriptor sets, texel-buffer views, push constants, timestamps when
//! profiled), zero fills, buffer copies and barriers.

use ash::vk;

use super::kernels::descriptor_type;
use super::{Binding, ComputeKernel, GpuBuffer, GpuContext, MAX_TIMED_DISPATCHES, TexelFormat};
use crate::gpu::error::{GpuError, vk_err};

/// Records dispatches and barriers into the command buffer of one [`GpuContext::submit`].
pub struct Recorder<'a> {
    pub(super) ctx: &'a GpuContext,
    pub(super) cmd: vk::CommandBuffer,
    pub(super) descriptor_pool: vk::DescriptorPool,
    /// Texel-buffer views created for this submission (released with its descriptor pool).
    pub(super) views: &'a std::cell::RefCell<Vec<vk::BufferView>>,
    /// Timestamp queries when profiling: two per timed dispatch.
    pub(super) query_pool: Option<vk::QueryPool>,
    /// Kernel names of the timed dispatches, in order.
    pub(super) timed: Vec<String>,
}

impl std::fmt::Debug for Recorder<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder").finish_non_exhaustive()
    }
}

impl Recorder<'_> {
    /// Binds `buffers` to bindings 0.. of `kernel` (a texel binding views the whole buffer),
    /// sets its push constants and dispatches `groups` workgroups. Checks the interface (buffer
    /// count, push size, texel count, group limit).
    pub fn dispatch(
        &mut self,
        kernel: &ComputeKernel,
        buffers: &[&GpuBuffer],
        push_constants: &[u8],
        groups: [u32; 3],
    ) -> Result<(), GpuError> {
        let mismatch = |reason: String| GpuError::Shader {
            name: kernel.name.clone(),
            reason,
        };
        if buffers.len() != kernel.bindings.len() {
            return Err(mismatch(format!(
                "{} buffers bound, the kernel has {} bindings",
                buffers.len(),
                kernel.bindings.len()
            )));
        }
        if push_constants.len() != kernel.push_constant_bytes as usize {
            return Err(mismatch(format!(
                "{} push-constant bytes given, the kernel takes {}",
                push_constants.len(),
                kernel.push_constant_bytes
            )));
        }
        let max_groups = self.ctx.report.max_compute_workgroup_count_x;
        if groups[0] > max_groups {
            return Err(GpuError::LimitTooSmall {
                device: self.ctx.report.name.clone(),
                limit: "maxComputeWorkGroupCount[0]",
                required: u64::from(groups[0]),
                actual: u64::from(max_groups),
            });
        }
        let d = &self.ctx.device;
        let layouts = [kernel.set_layout];
        // SAFETY (whole block): objects of this device; the set lives until the pool is
        // destroyed after the submission completed.
        unsafe {
            let set = d
                .allocate_descriptor_sets(
                    &vk::DescriptorSetAllocateInfo::default()
                        .descriptor_pool(self.descriptor_pool)
                        .set_layouts(&layouts),
                )
                .map_err(vk_err("vkAllocateDescriptorSets"))?[0];
            let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
                .iter()
                .map(|b| {
                    [vk::DescriptorBufferInfo::default()
                        .buffer(b.raw)
                        .offset(0)
                        .range(vk::WHOLE_SIZE)]
                })
                .collect();
            let mut texel_views = Vec::with_capacity(buffers.len());
            for (b, kind) in buffers.iter().zip(&kernel.bindings) {
                texel_views.push(match kind {
                    Binding::Storage => [vk::BufferView::null()],
                    Binding::Texel(format) => [self.texel_view(b, *format)?],
                });
            }
            let writes: Vec<_> = infos
                .iter()
                .zip(&texel_views)
                .zip(&kernel.bindings)
                .enumerate()
                .map(|(binding, ((info, view), kind))| {
                    let write = vk::WriteDescriptorSet::default()
                        .dst_set(set)
                        .dst_binding(binding as u32)
                        .descriptor_type(descriptor_type(*kind));
                    match kind {
                        Binding::Storage => write.buffer_info(info),
                        Binding::Texel(_) => write.texel_buffer_view(view),
                    }
                })
                .collect();
            d.update_descriptor_sets(&writes, &[]);
            d.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, kernel.pipeline);
            d.cmd_bind_descriptor_sets(
                self.cmd,
                vk::PipelineBindPoint::COMPUTE,
                kernel.layout,
                0,
                &[set],
                &[],
            );
            if !push_constants.is_empty() {
                d.cmd_push_constants(
                    self.cmd,
                    kernel.layout,
                    vk::ShaderStageFlags::COMPUTE,
                    0,
                    push_constants,
                );
            }
            let query = match self.query_pool {
                Some(q) if (self.timed.len() as u32) < MAX_TIMED_DISPATCHES => {
                    let first = 2 * self.timed.len() as u32;
                    self.timed.push(kernel.name.clone());
                    Some((q, first))
                }
                _ => None,
            };
            if let Some((q, first)) = query {
                d.cmd_write_timestamp(self.cmd, vk::PipelineStageFlags::COMPUTE_SHADER, q, first);
            }
            d.cmd_dispatch(self.cmd, groups[0], groups[1], groups[2]);
            if let Some((q, first)) = query {
                d.cmd_write_timestamp(
                    self.cmd,
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    q,
                    first + 1,
                );
            }
        }
        Ok(())
    }

    /// A view of the whole of `buffer` as texels of `format`, released with the submission.
    fn texel_view(
        &self,
        buffer: &GpuBuffer,
        format: TexelFormat,
    ) -> Result<vk::BufferView, GpuError> {
        // Buffers hold at least 16 bytes (create_buffer): at least one texel.
        let texels = buffer.size_bytes.max(16) / format.bytes();
        let limit = self.ctx.report.max_texel_buffer_elements;
        if texels > limit {
            return Err(GpuError::LimitTooSmall {
                device: self.ctx.report.name.clone(),
                limit: "maxTexelBufferElements",
                required: texels,
                actual: limit,
            });
        }
        let info = vk::BufferViewCreateInfo::default()
            .buffer(buffer.raw)
            .format(format.vk())
            .offset(0)
            .range(texels * format.bytes());
        // SAFETY: a buffer of this device created with UNIFORM_TEXEL_BUFFER usage; the range
        // lies inside it and is within the device's texel limit; the view is destroyed after
        // the submission completed.
        let view = unsafe { self.ctx.device.create_buffer_view(&info, None) }
            .map_err(vk_err("vkCreateBufferView"))?;
        self.views.borrow_mut().push(view);
        Ok(view)
    }

    /// Sets every byte of `buffer` to zero (a transfer command), then makes that visible to
    /// the shaders recorded after it.
    pub fn fill_zero(&mut self, buffer: &GpuBuffer) {
        let barrier = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE)];
        // SAFETY: recording into a command buffer in the recording state; the buffer belongs to
        // this device and was created with TRANSFER_DST usage (every GpuBuffer is).
        unsafe {
            self.ctx
                .device
                .cmd_fill_buffer(self.cmd, buffer.raw, 0, vk::WHOLE_SIZE, 0);
            self.ctx.device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::DependencyFlags::empty(),
                &barrier,
                &[],
                &[],
            );
        }
    }

    /// Copies the first `bytes` bytes of `src` to the start of `dst` (a transfer command), after
    /// every shader write recorded before it, and makes the copy visible to the shaders recorded
    /// after it. The caller keeps `bytes` within both buffers (checked: a longer copy is an
    /// error naming the buffers).
    pub fn copy_buffer(
        &mut self,
        src: &GpuBuffer,
        dst: &GpuBuffer,
        bytes: u64,
    ) -> Result<(), GpuError> {
        self.copy_region(src, 0, dst, 0, bytes)
    }

    /// As [`Self::copy_buffer`], from byte `src_offset` of `src` to byte `dst_offset` of `dst`.
    pub fn copy_region(
        &mut self,
        src: &GpuBuffer,
        src_offset: u64,
        dst: &GpuBuffer,
        dst_offset: u64,
        bytes: u64,
    ) -> Result<(), GpuError> {
        for (b, offset) in [(src, src_offset), (dst, dst_offset)] {
            if offset + bytes > b.size_bytes {
                return Err(GpuError::BufferRange {
                    name: b.name.clone(),
                    requested_bytes: offset + bytes,
                    capacity_bytes: b.size_bytes,
                });
            }
        }
        if bytes == 0 {
            return Ok(());
        }
        let before = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ | vk::AccessFlags::TRANSFER_WRITE)];
        let after = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE)];
        let region = [vk::BufferCopy::default()
            .src_offset(src_offset)
            .dst_offset(dst_offset)
            .size(bytes)];
        // SAFETY: recording into a command buffer in the recording state; both buffers belong to
        // this device, were created with TRANSFER_SRC | TRANSFER_DST usage (every GpuBuffer is)
        // and hold the copied ranges (checked above).
        unsafe {
            let d = &self.ctx.device;
            d.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &before,
                &[],
                &[],
            );
            d.cmd_copy_buffer(self.cmd, src.raw, dst.raw, &region);
            d.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::DependencyFlags::empty(),
                &after,
                &[],
                &[],
            );
        }
        Ok(())
    }

    /// Makes every shader write before it visible to every shader read/write after it.
    pub fn compute_barrier(&mut self) {
        let barrier = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE)
            .dst_access_mask(vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE)];
        // SAFETY: recording into a command buffer in the recording state.
        unsafe {
            self.ctx.device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::DependencyFlags::empty(),
                &barrier,
                &[],
                &[],
            );
        }
    }
}
