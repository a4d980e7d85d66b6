//! One Vulkan device opened for compute: queue, command pool, memory through gpu-allocator
//! (with current and peak use), storage buffers, compute kernels and one-shot submissions.

use std::mem::ManuallyDrop;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use ash::vk;
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};

use super::devices::{DeviceReport, REQUIRED_API, VulkanInstance, version_string};
use super::error::{GpuError, vk_err};

/// Which device to open.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum DeviceChoice {
    /// The most capable kind present: discrete > integrated > virtual > CPU (lavapipe).
    #[default]
    Best,
    /// Position in `s3tir-train devices`.
    Index(usize),
    /// First device whose name contains this text (e.g. `llvmpipe`).
    NameContains(String),
}

/// Kernel work-group sizes the shaders use (`local_size_*` in `shaders/`): at most 256
/// invocations, 256 along x, 16 along y. Vulkan guarantees only 128 invocations, so devices
/// are checked when a context opens.
pub const WORKGROUP_INVOCATIONS_USED: u32 = 256;
pub const WORKGROUP_SIZE_USED: [u32; 2] = [256, 16];

/// Longest wait for one submission before the device is declared hung. Far above the
/// longest submission seen (a whole training step at 640×512 on lavapipe takes seconds).
pub const SUBMIT_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(300);

/// Refuses a device whose work-group limits are below what the shaders use.
pub fn check_workgroup_limits(report: &DeviceReport) -> Result<(), GpuError> {
    let too_small = |limit: &'static str, required: u32, actual: u32| GpuError::LimitTooSmall {
        device: report.name.clone(),
        limit,
        required: u64::from(required),
        actual: u64::from(actual),
    };
    if report.max_compute_workgroup_invocations < WORKGROUP_INVOCATIONS_USED {
        return Err(too_small(
            "maxComputeWorkGroupInvocations",
            WORKGROUP_INVOCATIONS_USED,
            report.max_compute_workgroup_invocations,
        ));
    }
    for (axis, (limit, need)) in ["maxComputeWorkGroupSize[0]", "maxComputeWorkGroupSize[1]"]
        .into_iter()
        .zip(WORKGROUP_SIZE_USED)
        .enumerate()
    {
        let have = report.max_compute_workgroup_size[axis];
        if have < need {
            return Err(too_small(limit, need, have));
        }
    }
    Ok(())
}

/// Waits for a fence in one-second slices up to `limit`: a hung device becomes
/// [`GpuError::SubmitTimeout`] instead of a wait for ever. `wait(ns)` is one
/// `vkWaitForFences` with that timeout.
pub fn wait_bounded(
    mut wait: impl FnMut(u64) -> Result<(), vk::Result>,
    limit: std::time::Duration,
    device: &str,
) -> Result<(), GpuError> {
    let start = std::time::Instant::now();
    let slice = std::time::Duration::from_secs(1).min(limit);
    loop {
        match wait(u64::try_from(slice.as_nanos()).unwrap_or(u64::MAX)) {
            Ok(()) => return Ok(()),
            Err(vk::Result::TIMEOUT) if start.elapsed() < limit => {}
            Err(vk::Result::TIMEOUT) => {
                return Err(GpuError::SubmitTimeout {
                    device: device.to_owned(),
                    waited_s: start.elapsed().as_secs_f64(),
                });
            }
            Err(e) => return Err(vk_err("vkWaitForFences")(e)),
        }
    }
}

/// Options for opening a context.
#[derive(Debug, Clone, Default)]
pub struct ContextOptions {
    pub device: DeviceChoice,
    /// Do not enable float atomics even if the device has them: forces the fallback paths
    /// (what a Raspberry Pi 5's driver would take) on any device, for tests.
    pub disable_float_atomics: bool,
}

/// What the opened device lets kernels use; kernels pick their variant from this.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capabilities {
    /// `atomicAdd(float)` on storage buffers is enabled.
    pub float_atomic_add: bool,
    /// Subgroup arithmetic in compute shaders.
    pub subgroup_arithmetic: bool,
    /// Timestamp queries on the compute queue.
    pub compute_timestamps: bool,
}

/// Where a buffer lives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MemoryLocation {
    /// Host-visible, written by the CPU and read by kernels.
    Upload,
    /// Host-visible, written by kernels and read back by the CPU.
    Readback,
    /// Device-local; not mappable.
    DeviceOnly,
}

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
    fn vk(self) -> vk::Format {
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

/// A storage buffer and its memory. Release it with [`GpuContext::destroy_buffer`].
#[derive(Debug)]
pub struct GpuBuffer {
    raw: vk::Buffer,
    allocation: Allocation,
    size_bytes: u64,
    name: String,
    location: MemoryLocation,
}

impl GpuBuffer {
    pub fn size_bytes(&self) -> u64 {
        self.size_bytes
    }
    pub fn location(&self) -> MemoryLocation {
        self.location
    }
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// A compute pipeline with its interface: `bindings` 0.. in set 0 and a push constant block of
/// `push_constant_bytes`. Release with [`GpuContext::destroy_kernel`].
#[derive(Debug)]
pub struct ComputeKernel {
    name: String,
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    set_layout: vk::DescriptorSetLayout,
    bindings: Vec<Binding>,
    push_constant_bytes: u32,
}

impl ComputeKernel {
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// An open device. Dropping it waits for the device to be idle and releases everything it owns.
pub struct GpuContext {
    allocator: ManuallyDrop<Mutex<Allocator>>,
    command_pool: vk::CommandPool,
    queue: vk::Queue,
    queue_family: u32,
    device: ash::Device,
    report: DeviceReport,
    caps: Capabilities,
    allocated_bytes: AtomicU64,
    peak_allocated_bytes: AtomicU64,
    /// Host reads of GPU-written data ([`Self::read_at`]) and their bytes, and submissions:
    /// each read waits for the GPU (`s3tir-train bench` reports them per step).
    host_reads: AtomicU64,
    host_read_bytes: AtomicU64,
    submissions: AtomicU64,
    /// A submission timed out ([`SUBMIT_TIMEOUT`]): the device is leaked on drop, not waited
    /// for (waiting would hang) nor destroyed under running work.
    hung: std::sync::atomic::AtomicBool,
    // Last: destroyed after the device (see Drop).
    instance: ManuallyDrop<VulkanInstance>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("device", &self.report.name)
            .field("caps", &self.caps)
            .finish_non_exhaustive()
    }
}

impl GpuContext {
    /// Opens the chosen device for compute, checking up front that it offers Vulkan 1.2 and a
    /// compute queue, and enabling float atomics when present (unless disabled).
    pub fn new(options: &ContextOptions) -> Result<Self, GpuError> {
        let instance = VulkanInstance::new()?;
        let physical = instance.physical_devices()?;
        let reports = physical
            .iter()
            .enumerate()
            .map(|(i, pd)| instance.describe(i, *pd))
            .collect::<Result<Vec<_>, _>>()?;
        let chosen = match &options.device {
            DeviceChoice::Best => reports
                .iter()
                .enumerate()
                .max_by_key(|(i, r)| (r.preference(), std::cmp::Reverse(*i)))
                .map(|(i, _)| i)
                .ok_or(GpuError::NoDevice)?,
            DeviceChoice::Index(index) => {
                if *index >= reports.len() {
                    return Err(GpuError::DeviceIndexOutOfRange {
                        index: *index,
                        count: reports.len(),
                    });
                }
                *index
            }
            DeviceChoice::NameContains(pattern) => reports
                .iter()
                .position(|r| r.name.contains(pattern.as_str()))
                .ok_or_else(|| GpuError::NoDeviceNamed {
                    pattern: pattern.clone(),
                })?,
        };
        let pd = physical[chosen];
        let report = reports[chosen].clone();
        if report.api_version_raw < REQUIRED_API {
            return Err(GpuError::MissingFeature {
                device: report.name,
                feature: format!(
                    "Vulkan 1.2 (it offers {})",
                    version_string(report.api_version_raw)
                ),
            });
        }
        check_workgroup_limits(&report)?;
        let inst = instance.raw();
        // SAFETY: `pd` belongs to `instance`.
        let families = unsafe { inst.get_physical_device_queue_family_properties(pd) };
        let queue_family = families
            .iter()
            .position(|q| q.queue_flags.contains(vk::QueueFlags::COMPUTE))
            .ok_or_else(|| GpuError::MissingFeature {
                device: report.name.clone(),
                feature: "a queue family with compute".to_owned(),
            })? as u32;
        let compute_timestamps = families[queue_family as usize].timestamp_valid_bits > 0;

        let want_atomics = report.float_atomics.buffer_f32_add && !options.disable_float_atomics;
        let mut atomic_features = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
            .shader_buffer_float32_atomic_add(want_atomics)
            .shader_buffer_float32_atomics(want_atomics && report.float_atomics.buffer_f32_exchange)
            .shader_shared_float32_atomic_add(want_atomics && report.float_atomics.shared_f32_add);
        let extensions = if want_atomics {
            vec![ash::ext::shader_atomic_float::NAME.as_ptr()]
        } else {
            Vec::new()
        };
        let priorities = [1.0f32];
        let queue_info = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family)
            .queue_priorities(&priorities)];
        let mut device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .enabled_extension_names(&extensions);
        if want_atomics {
            device_info = device_info.push_next(&mut atomic_features);
        }
        // SAFETY: valid create info; the device is destroyed in Drop before the instance.
        let device = unsafe { inst.create_device(pd, &device_info, None) }
            .map_err(vk_err("vkCreateDevice"))?;
        // SAFETY: family/index exist (requested above).
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: valid device.
        let command_pool = match unsafe { device.create_command_pool(&pool_info, None) } {
            Ok(p) => p,
            Err(result) => {
                // SAFETY: nothing else was created from the device yet.
                unsafe { device.destroy_device(None) };
                return Err(GpuError::Vk {
                    call: "vkCreateCommandPool",
                    result,
                });
            }
        };
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: inst.clone(),
            device: device.clone(),
            physical_device: pd,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: only the pool was created from the device.
                unsafe {
                    device.destroy_command_pool(command_pool, None);
                    device.destroy_device(None);
                }
                return Err(GpuError::Allocation {
                    name: "allocator".to_owned(),
                    bytes: 0,
                    reason: e.to_string(),
                });
            }
        };
        let caps = Capabilities {
            float_atomic_add: want_atomics,
            subgroup_arithmetic: report.has_subgroup_arithmetic(),
            compute_timestamps,
        };
        tracing::info!(device = %report.name, ?caps, "opened Vulkan device");
        Ok(Self {
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            command_pool,
            queue,
            queue_family,
            device,
            report,
            caps,
            allocated_bytes: AtomicU64::new(0),
            peak_allocated_bytes: AtomicU64::new(0),
            host_reads: AtomicU64::new(0),
            host_read_bytes: AtomicU64::new(0),
            submissions: AtomicU64::new(0),
            hung: std::sync::atomic::AtomicBool::new(false),
            instance: ManuallyDrop::new(instance),
        })
    }

    /// The instance the device was opened from.
    pub fn instance(&self) -> &VulkanInstance {
        &self.instance
    }

    pub fn report(&self) -> &DeviceReport {
        &self.report
    }

    pub fn capabilities(&self) -> Capabilities {
        self.caps
    }

    pub fn device(&self) -> &ash::Device {
        &self.device
    }

    pub fn queue_family(&self) -> u32 {
        self.queue_family
    }

    /// Bytes of buffer memory currently allocated through this context.
    pub fn allocated_bytes(&self) -> u64 {
        self.allocated_bytes.load(Ordering::Relaxed)
    }

    /// Largest [`Self::allocated_bytes`] seen since the context opened.
    pub fn peak_allocated_bytes(&self) -> u64 {
        self.peak_allocated_bytes.load(Ordering::Relaxed)
    }

    /// Traffic so far: (host reads of GPU data, bytes read, submissions).
    pub fn traffic(&self) -> (u64, u64, u64) {
        (
            self.host_reads.load(Ordering::Relaxed),
            self.host_read_bytes.load(Ordering::Relaxed),
            self.submissions.load(Ordering::Relaxed),
        )
    }

    /// Creates a storage buffer of `size_bytes`, checked against the device's storage-buffer
    /// range up front (lavapipe and small rig GPUs: 128 MiB).
    pub fn create_buffer(
        &self,
        name: &str,
        size_bytes: u64,
        location: MemoryLocation,
    ) -> Result<GpuBuffer, GpuError> {
        let limit = self.report.max_storage_buffer_range_bytes;
        if size_bytes > limit {
            return Err(GpuError::LimitTooSmall {
                device: self.report.name.clone(),
                limit: "maxStorageBufferRange",
                required: size_bytes,
                actual: limit,
            });
        }
        // At least one texel of every texel format (see `Recorder::texel_view`).
        let size = size_bytes.max(16);
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(
                vk::BufferUsageFlags::STORAGE_BUFFER
                    | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
                    | vk::BufferUsageFlags::TRANSFER_SRC
                    | vk::BufferUsageFlags::TRANSFER_DST,
            )
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let raw =
            unsafe { self.device.create_buffer(&info, None) }.map_err(vk_err("vkCreateBuffer"))?;
        // SAFETY: `raw` was just created from this device.
        let requirements = unsafe { self.device.get_buffer_memory_requirements(raw) };
        let alloc_location = match location {
            MemoryLocation::Upload => gpu_allocator::MemoryLocation::CpuToGpu,
            MemoryLocation::Readback => gpu_allocator::MemoryLocation::GpuToCpu,
            MemoryLocation::DeviceOnly => gpu_allocator::MemoryLocation::GpuOnly,
        };
        let allocation = self.lock_allocator().and_then(|mut a| {
            a.allocate(&AllocationCreateDesc {
                name,
                requirements,
                location: alloc_location,
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            })
            .map_err(|e| GpuError::Allocation {
                name: name.to_owned(),
                bytes: size,
                reason: e.to_string(),
            })
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: unbound buffer of this device, not in use.
                unsafe { self.device.destroy_buffer(raw, None) };
                return Err(e);
            }
        };
        // SAFETY: memory from the allocator satisfies `requirements`.
        if let Err(result) = unsafe {
            self.device
                .bind_buffer_memory(raw, allocation.memory(), allocation.offset())
        } {
            // SAFETY: as above.
            unsafe { self.device.destroy_buffer(raw, None) };
            if let Ok(mut a) = self.lock_allocator() {
                let _ = a.free(allocation);
            }
            return Err(GpuError::Vk {
                call: "vkBindBufferMemory",
                result,
            });
        }
        let now = self
            .allocated_bytes
            .fetch_add(allocation.size(), Ordering::Relaxed)
            + allocation.size();
        self.peak_allocated_bytes.fetch_max(now, Ordering::Relaxed);
        Ok(GpuBuffer {
            raw,
            allocation,
            size_bytes,
            name: name.to_owned(),
            location,
        })
    }

    /// Creates a host-visible buffer holding `data`.
    pub fn upload<T: bytemuck::Pod>(&self, name: &str, data: &[T]) -> Result<GpuBuffer, GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let mut buffer = self.create_buffer(name, bytes.len() as u64, MemoryLocation::Upload)?;
        self.write(&mut buffer, data)?;
        Ok(buffer)
    }

    /// Writes `data` at the start of a host-visible buffer.
    pub fn write<T: bytemuck::Pod>(
        &self,
        buffer: &mut GpuBuffer,
        data: &[T],
    ) -> Result<(), GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let capacity = buffer.size_bytes;
        let name = buffer.name.clone();
        let mapped = buffer
            .allocation
            .mapped_slice_mut()
            .ok_or_else(|| GpuError::BufferRange {
                name: name.clone(),
                requested_bytes: bytes.len() as u64,
                capacity_bytes: 0,
            })?;
        let dst = mapped
            .get_mut(..bytes.len())
            .filter(|_| bytes.len() as u64 <= capacity);
        let dst = dst.ok_or(GpuError::BufferRange {
            name,
            requested_bytes: bytes.len() as u64,
            capacity_bytes: capacity,
        })?;
        dst.copy_from_slice(bytes);
        Ok(())
    }

    /// Reads the first `count` elements of a host-visible buffer (after the work that wrote it
    /// has completed, e.g. after [`Self::submit`] returned).
    pub fn read<T: bytemuck::Pod>(
        &self,
        buffer: &GpuBuffer,
        count: usize,
    ) -> Result<Vec<T>, GpuError> {
        self.read_at(buffer, 0, count)
    }

    /// Reads `count` elements starting at element `first` of a host-visible buffer.
    pub fn read_at<T: bytemuck::Pod>(
        &self,
        buffer: &GpuBuffer,
        first: usize,
        count: usize,
    ) -> Result<Vec<T>, GpuError> {
        let size = std::mem::size_of::<T>();
        let (start, end) = (first * size, (first + count) * size);
        let out_of_range = || GpuError::BufferRange {
            name: buffer.name.clone(),
            requested_bytes: end as u64,
            capacity_bytes: buffer.size_bytes,
        };
        if end as u64 > buffer.size_bytes {
            return Err(out_of_range());
        }
        self.host_reads.fetch_add(1, Ordering::Relaxed);
        self.host_read_bytes
            .fetch_add((end - start) as u64, Ordering::Relaxed);
        let mapped = buffer.allocation.mapped_slice().ok_or_else(out_of_range)?;
        let bytes = mapped.get(start..end).ok_or_else(out_of_range)?;
        // Copy element-wise: mapped memory need not be aligned for T.
        Ok(bytes
            .chunks_exact(size)
            .map(bytemuck::pod_read_unaligned)
            .collect())
    }

    /// Releases a buffer. The caller guarantees no pending work uses it ([`Self::submit`]
    /// waits for completion, so buffers are free after it returns).
    pub fn destroy_buffer(&self, buffer: GpuBuffer) {
        let size = buffer.allocation.size();
        // SAFETY: the buffer belongs to this device and no work is pending on it.
        unsafe { self.device.destroy_buffer(buffer.raw, None) };
        if let Ok(mut a) = self.lock_allocator()
            && let Err(e) = a.free(buffer.allocation)
        {
            tracing::warn!(buffer = %buffer.name, error = %e, "freeing GPU memory failed");
        }
        self.allocated_bytes.fetch_sub(size, Ordering::Relaxed);
    }

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
                    return Err(GpuError::Shader {
                        name: name.to_owned(),
                        reason: format!("vkCreateShaderModule: {result}"),
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
                    Err(GpuError::Shader {
                        name: name.to_owned(),
                        reason: format!("vkCreateComputePipelines: {result}"),
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

    /// Records work with `record` into one command buffer, submits it and waits for completion.
    pub fn submit<F>(&self, record: F) -> Result<(), GpuError>
    where
        F: FnOnce(&mut Recorder<'_>) -> Result<(), GpuError>,
    {
        self.submit_inner(record, false).map(|_| ())
    }

    /// Like [`Self::submit`], and times every dispatch with timestamp queries: returns one
    /// entry per dispatch, in recording order. Empty when the queue has no timestamps.
    pub fn submit_profiled<F>(&self, record: F) -> Result<Vec<KernelTiming>, GpuError>
    where
        F: FnOnce(&mut Recorder<'_>) -> Result<(), GpuError>,
    {
        self.submit_inner(record, self.caps.compute_timestamps)
    }

    fn submit_inner<F>(&self, record: F, profile: bool) -> Result<Vec<KernelTiming>, GpuError>
    where
        F: FnOnce(&mut Recorder<'_>) -> Result<(), GpuError>,
    {
        self.submissions.fetch_add(1, Ordering::Relaxed);
        let d = &self.device;
        let pool_sizes = [
            vk::DescriptorPoolSize::default()
                .ty(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(4096),
            vk::DescriptorPoolSize::default()
                .ty(vk::DescriptorType::UNIFORM_TEXEL_BUFFER)
                .descriptor_count(1024),
        ];
        // Texel-buffer views of this submission's dispatches, released after it completed.
        let views = std::cell::RefCell::new(Vec::new());
        // SAFETY (whole block): valid device; the pools and command buffer are released before
        // returning, after the fence wait (or on the error paths without a submission).
        unsafe {
            let descriptor_pool = d
                .create_descriptor_pool(
                    &vk::DescriptorPoolCreateInfo::default()
                        .max_sets(512)
                        .pool_sizes(&pool_sizes),
                    None,
                )
                .map_err(vk_err("vkCreateDescriptorPool"))?;
            let query_pool = if profile {
                match d.create_query_pool(
                    &vk::QueryPoolCreateInfo::default()
                        .query_type(vk::QueryType::TIMESTAMP)
                        .query_count(2 * MAX_TIMED_DISPATCHES),
                    None,
                ) {
                    Ok(q) => Some(q),
                    Err(result) => {
                        d.destroy_descriptor_pool(descriptor_pool, None);
                        return Err(GpuError::Vk {
                            call: "vkCreateQueryPool",
                            result,
                        });
                    }
                }
            } else {
                None
            };
            let release_pools = || {
                for v in views.borrow_mut().drain(..) {
                    d.destroy_buffer_view(v, None);
                }
                d.destroy_descriptor_pool(descriptor_pool, None);
                if let Some(q) = query_pool {
                    d.destroy_query_pool(q, None);
                }
            };
            let cmd = match d.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(self.command_pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1),
            ) {
                Ok(c) => c[0],
                Err(result) => {
                    release_pools();
                    return Err(GpuError::Vk {
                        call: "vkAllocateCommandBuffers",
                        result,
                    });
                }
            };
            let result = (|| {
                d.begin_command_buffer(
                    cmd,
                    &vk::CommandBufferBeginInfo::default()
                        .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
                )
                .map_err(vk_err("vkBeginCommandBuffer"))?;
                if let Some(q) = query_pool {
                    d.cmd_reset_query_pool(cmd, q, 0, 2 * MAX_TIMED_DISPATCHES);
                }
                let mut recorder = Recorder {
                    ctx: self,
                    cmd,
                    descriptor_pool,
                    views: &views,
                    query_pool,
                    timed: Vec::new(),
                };
                record(&mut recorder)?;
                let timed = std::mem::take(&mut recorder.timed);
                d.end_command_buffer(cmd)
                    .map_err(vk_err("vkEndCommandBuffer"))?;
                let fence = d
                    .create_fence(&vk::FenceCreateInfo::default(), None)
                    .map_err(vk_err("vkCreateFence"))?;
                let cmds = [cmd];
                let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
                let waited = d
                    .queue_submit(self.queue, &submit, fence)
                    .map_err(vk_err("vkQueueSubmit"))
                    .and_then(|()| {
                        wait_bounded(
                            |ns| d.wait_for_fences(&[fence], true, ns),
                            SUBMIT_TIMEOUT,
                            &self.report.name,
                        )
                    });
                if let Err(GpuError::SubmitTimeout { .. }) = &waited {
                    // The device may still run the commands: nothing they use may be freed
                    // (the fence included), and waiting for idle would hang too.
                    return waited.map(|()| Vec::new());
                }
                if waited.is_err() {
                    // Do not free resources the device may still use.
                    let _ = d.device_wait_idle();
                }
                d.destroy_fence(fence, None);
                waited?;
                let (Some(q), false) = (query_pool, timed.is_empty()) else {
                    return Ok(Vec::new());
                };
                let mut ticks = vec![0u64; 2 * timed.len()];
                d.get_query_pool_results(
                    q,
                    0,
                    &mut ticks,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
                .map_err(vk_err("vkGetQueryPoolResults"))?;
                let period_ns = f64::from(self.report.timestamp_period_ns);
                Ok(timed
                    .into_iter()
                    .zip(ticks.chunks_exact(2))
                    .map(|(kernel, t)| KernelTiming {
                        kernel,
                        duration_ns: t[1].saturating_sub(t[0]) as f64 * period_ns,
                    })
                    .collect())
            })();
            if let Err(GpuError::SubmitTimeout { .. }) = &result {
                // The hung submission may still use the command buffer, its descriptor pool
                // and views: leaked, not freed (see SUBMIT_TIMEOUT).
                self.hung.store(true, Ordering::Relaxed);
                return result;
            }
            d.free_command_buffers(self.command_pool, &[cmd]);
            release_pools();
            result
        }
    }

    fn lock_allocator(&self) -> Result<std::sync::MutexGuard<'_, Allocator>, GpuError> {
        self.allocator.lock().map_err(|_| GpuError::Allocation {
            name: "allocator".to_owned(),
            bytes: 0,
            reason: "allocator lock poisoned by a panic in another thread".to_owned(),
        })
    }
}

/// Records dispatches and barriers into the command buffer of one [`GpuContext::submit`].
pub struct Recorder<'a> {
    ctx: &'a GpuContext,
    cmd: vk::CommandBuffer,
    descriptor_pool: vk::DescriptorPool,
    /// Texel-buffer views created for this submission (released with its descriptor pool).
    views: &'a std::cell::RefCell<Vec<vk::BufferView>>,
    /// Timestamp queries when profiling: two per timed dispatch.
    query_pool: Option<vk::QueryPool>,
    /// Kernel names of the timed dispatches, in order.
    timed: Vec<String>,
}

/// Most dispatches one profiled submission times; later ones run untimed.
pub const MAX_TIMED_DISPATCHES: u32 = 1024;

/// GPU time of one dispatch, from timestamp queries.
#[derive(Debug, Clone, PartialEq)]
pub struct KernelTiming {
    pub kernel: String,
    pub duration_ns: f64,
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

fn descriptor_type(binding: Binding) -> vk::DescriptorType {
    match binding {
        Binding::Storage => vk::DescriptorType::STORAGE_BUFFER,
        Binding::Texel(_) => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
    }
}

impl Drop for GpuContext {
    fn drop(&mut self) {
        if self.hung.load(Ordering::Relaxed) {
            // A hung device: waiting would block for ever and destroying it under running
            // work is undefined. Everything is leaked; the process is about to report the
            // error and exit.
            return;
        }
        // SAFETY: waits for all work, then releases objects in reverse order of creation:
        // allocator (frees its memory blocks), command pool, device, instance.
        unsafe {
            let _ = self.device.device_wait_idle();
            ManuallyDrop::drop(&mut self.allocator);
            self.device.destroy_command_pool(self.command_pool, None);
            self.device.destroy_device(None);
            ManuallyDrop::drop(&mut self.instance);
        }
    }
}

#[cfg(test)]
mod tests {
    //! Proves: a fence wait gives up after its limit with `SubmitTimeout` (a hung device is an
    //! error, not a wait for ever) and passes other Vulkan errors through; devices whose
    //! work-group limits are below what the shaders use are refused by name. The real device
    //! paths are tested on lavapipe in `tests/gpu_*.rs`.
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_fence_that_never_signals_times_out() {
        let mut calls = 0;
        let r = wait_bounded(
            |ns| {
                calls += 1;
                assert!(ns <= 1_000_000_000, "slices of at most a second");
                std::thread::sleep(std::time::Duration::from_millis(5));
                Err(vk::Result::TIMEOUT)
            },
            std::time::Duration::from_millis(30),
            "stuck gpu",
        );
        match r {
            Err(GpuError::SubmitTimeout { device, waited_s }) => {
                assert_eq!(device, "stuck gpu");
                assert!(waited_s >= 0.03, "waited {waited_s} s");
            }
            other => panic!("expected SubmitTimeout, got {other:?}"),
        }
        assert!(calls >= 2, "waited in slices: {calls} calls");
        let mut n = 0;
        assert!(
            wait_bounded(
                |_| {
                    n += 1;
                    if n < 3 {
                        Err(vk::Result::TIMEOUT)
                    } else {
                        Ok(())
                    }
                },
                std::time::Duration::from_secs(60),
                "slow gpu",
            )
            .is_ok(),
            "a fence that signals within the limit is a success"
        );
        assert!(matches!(
            wait_bounded(
                |_| Err(vk::Result::ERROR_DEVICE_LOST),
                SUBMIT_TIMEOUT,
                "lost"
            ),
            Err(GpuError::Vk { .. })
        ));
    }

    #[test]
    fn devices_below_the_shaders_work_group_sizes_are_refused() {
        let instance = VulkanInstance::new().unwrap();
        let pd = instance.physical_devices().unwrap()[0];
        let good = instance.describe(0, pd).unwrap();
        check_workgroup_limits(&good).unwrap();
        let mut small = good.clone();
        small.max_compute_workgroup_invocations = 128; // the Vulkan minimum
        let err = check_workgroup_limits(&small).unwrap_err().to_string();
        assert!(
            err.contains("maxComputeWorkGroupInvocations") && err.contains("256"),
            "{err}"
        );
        let mut narrow = good;
        narrow.max_compute_workgroup_size = [128, 128, 64];
        let err = check_workgroup_limits(&narrow).unwrap_err().to_string();
        assert!(err.contains("maxComputeWorkGroupSize[0]"), "{err}");
    }
}
