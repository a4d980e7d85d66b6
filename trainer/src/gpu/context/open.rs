//! Opening a device for compute: which device ([`DeviceChoice`]), the checks made before
//! anything is created (Vulkan 1.2, the shaders' work-group sizes, a compute queue), the
//! features enabled (float atomics unless disabled) and the queue, command pool and allocator.

use std::mem::ManuallyDrop;
use std::sync::Mutex;
use std::sync::atomic::AtomicU64;

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};

use super::{Capabilities, GpuContext};
use crate::gpu::devices::{DeviceReport, REQUIRED_API, VulkanInstance, version_string};
use crate::gpu::error::{GpuError, vk_err};

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

/// Options for opening a context.
#[derive(Debug, Clone, Default)]
pub struct ContextOptions {
    pub device: DeviceChoice,
    /// Do not enable float atomics even if the device has them: forces the fallback paths
    /// (what a Raspberry Pi 5's driver would take) on any device, for tests.
    pub disable_float_atomics: bool,
}

impl GpuContext {
    /// Opens the chosen device for compute, checking up front that it offers Vulkan 1.2 and a
    /// compute queue, and enabling float atomics when present (unless disabled).
    // Why this stays long: Vulkan's opening sequence (instance, device choice, features,
    // queue, command pool), each step's failure releasing what the previous ones created.
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
            Err(source) => {
                // SAFETY: only the pool was created from the device.
                unsafe {
                    device.destroy_command_pool(command_pool, None);
                    device.destroy_device(None);
                }
                return Err(GpuError::Allocation {
                    name: "allocator".to_owned(),
                    bytes: 0,
                    source,
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
}

#[cfg(test)]
mod tests {
    //! Proves: devices whose work-group limits are below what the shaders use are refused by
    //! name. Opening a real device is tested on lavapipe in `tests/gpu_*.rs`.
    #![allow(clippy::unwrap_used)]
    use super::*;

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
