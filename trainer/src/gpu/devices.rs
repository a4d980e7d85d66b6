//! The Vulkan instance and device reports: what `s3tir-train devices` prints and what the
//! compute context checks before it opens a device.

use std::ffi::CStr;

use ash::vk;
use serde::Serialize;

use super::error::{GpuError, vk_err};

/// Oldest device API the kernels target (glslc `--target-env=vulkan1.2`).
pub const REQUIRED_API: u32 = vk::API_VERSION_1_2;

/// A loaded Vulkan library and an instance created from it; destroyed on drop.
pub struct VulkanInstance {
    // Field order matters for drop: `instance` is destroyed in Drop, `entry` (the loaded
    // library) is dropped after it.
    instance: ash::Instance,
    entry: ash::Entry,
    api_version: u32,
}

impl std::fmt::Debug for VulkanInstance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VulkanInstance")
            .field("api_version", &version_string(self.api_version))
            .finish_non_exhaustive()
    }
}

impl VulkanInstance {
    /// Loads the Vulkan loader (dlopen, so a missing loader is an error, not a link failure)
    /// and creates an instance at the highest API version up to 1.3 the loader offers.
    pub fn new() -> Result<Self, GpuError> {
        // SAFETY: loading the system Vulkan loader runs its initialisers; that is its contract.
        let entry =
            unsafe { ash::Entry::load() }.map_err(|source| GpuError::LoaderMissing { source })?;
        // SAFETY: plain query on a loaded entry.
        let loader_version = unsafe { entry.try_enumerate_instance_version() }
            .map_err(vk_err("vkEnumerateInstanceVersion"))?
            .unwrap_or(vk::API_VERSION_1_0);
        if loader_version < vk::API_VERSION_1_1 {
            return Err(GpuError::MissingFeature {
                device: "Vulkan loader".to_owned(),
                feature: format!(
                    "instance API 1.1 (loader offers {})",
                    version_string(loader_version)
                ),
            });
        }
        let api_version = loader_version.min(vk::API_VERSION_1_3);
        let app = vk::ApplicationInfo::default()
            .application_name(c"s3tir")
            .engine_name(c"s3tir-trainer")
            .api_version(api_version);
        let create_info = vk::InstanceCreateInfo::default().application_info(&app);
        // SAFETY: valid create info; the instance is destroyed in Drop.
        let instance = unsafe { entry.create_instance(&create_info, None) }.map_err(|result| {
            // The loader answers INCOMPATIBLE_DRIVER when it found no driver (ICD) at all.
            if result == vk::Result::ERROR_INCOMPATIBLE_DRIVER {
                GpuError::NoDevice
            } else {
                GpuError::Vk {
                    call: "vkCreateInstance",
                    result,
                }
            }
        })?;
        Ok(Self {
            instance,
            entry,
            api_version,
        })
    }

    pub fn raw(&self) -> &ash::Instance {
        &self.instance
    }

    pub fn entry(&self) -> &ash::Entry {
        &self.entry
    }

    /// Instance API version.
    pub fn api_version(&self) -> u32 {
        self.api_version
    }

    /// Physical devices in the loader's order; [`GpuError::NoDevice`] when there is none.
    pub fn physical_devices(&self) -> Result<Vec<vk::PhysicalDevice>, GpuError> {
        // SAFETY: valid instance.
        let devices = unsafe { self.instance.enumerate_physical_devices() }
            .map_err(vk_err("vkEnumeratePhysicalDevices"))?;
        if devices.is_empty() {
            return Err(GpuError::NoDevice);
        }
        Ok(devices)
    }

    /// Reports every device.
    pub fn reports(&self) -> Result<Vec<DeviceReport>, GpuError> {
        self.physical_devices()?
            .into_iter()
            .enumerate()
            .map(|(index, pd)| self.describe(index, pd))
            .collect()
    }

    /// Queries what one device offers.
    pub fn describe(&self, index: usize, pd: vk::PhysicalDevice) -> Result<DeviceReport, GpuError> {
        let inst = &self.instance;
        // SAFETY: `pd` comes from this instance; every struct below is valid for the query.
        unsafe {
            let props = inst.get_physical_device_properties(pd);
            let extensions = inst
                .enumerate_device_extension_properties(pd)
                .map_err(vk_err("vkEnumerateDeviceExtensionProperties"))?;
            let has_ext = |name: &CStr| {
                extensions
                    .iter()
                    .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name))
            };

            let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
            let mut driver = vk::PhysicalDeviceDriverProperties::default();
            let has_driver_props = props.api_version >= vk::API_VERSION_1_2;
            {
                let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut subgroup);
                if has_driver_props {
                    props2 = props2.push_next(&mut driver);
                }
                inst.get_physical_device_properties2(pd, &mut props2);
            }

            let has_atomic_float = has_ext(ash::ext::shader_atomic_float::NAME);
            let mut atomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
            if has_atomic_float {
                let mut features2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut atomic);
                inst.get_physical_device_features2(pd, &mut features2);
            }

            let memory = inst.get_physical_device_memory_properties(pd);
            let memory_heaps = memory.memory_heaps[..memory.memory_heap_count as usize]
                .iter()
                .map(|h| MemoryHeap {
                    size_bytes: h.size,
                    device_local: h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL),
                })
                .collect();

            let queues = inst.get_physical_device_queue_family_properties(pd);
            let compute_timestamp_bits = queues
                .iter()
                .filter(|q| q.queue_flags.contains(vk::QueueFlags::COMPUTE))
                .map(|q| q.timestamp_valid_bits)
                .max()
                .unwrap_or(0);

            let name = props
                .device_name_as_c_str()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|_| "<unnamed>".to_owned());
            let (driver_name, driver_info) = if has_driver_props {
                (
                    driver
                        .driver_name_as_c_str()
                        .map(|s| s.to_string_lossy().into_owned())
                        .unwrap_or_default(),
                    driver
                        .driver_info_as_c_str()
                        .map(|s| s.to_string_lossy().into_owned())
                        .unwrap_or_default(),
                )
            } else {
                (String::new(), String::new())
            };
            let limits = &props.limits;
            Ok(DeviceReport {
                index,
                name,
                device_type: device_type_name(props.device_type).to_owned(),
                driver_name,
                driver_info,
                api_version: version_string(props.api_version),
                api_version_raw: props.api_version,
                memory_heaps,
                max_storage_buffer_range_bytes: u64::from(limits.max_storage_buffer_range),
                max_compute_shared_memory_bytes: limits.max_compute_shared_memory_size,
                max_per_stage_storage_buffers: limits.max_per_stage_descriptor_storage_buffers,
                max_texel_buffer_elements: u64::from(limits.max_texel_buffer_elements),
                max_compute_workgroup_invocations: limits.max_compute_work_group_invocations,
                max_compute_workgroup_size: limits.max_compute_work_group_size,
                max_compute_workgroup_count_x: limits.max_compute_work_group_count[0],
                subgroup_size: subgroup.subgroup_size,
                subgroup_operations: subgroup_operation_names(subgroup.supported_operations),
                subgroup_in_compute: subgroup
                    .supported_stages
                    .contains(vk::ShaderStageFlags::COMPUTE),
                float_atomics: FloatAtomics {
                    extension: has_atomic_float,
                    buffer_f32_add: atomic.shader_buffer_float32_atomic_add == vk::TRUE,
                    shared_f32_add: atomic.shader_shared_float32_atomic_add == vk::TRUE,
                    buffer_f32_exchange: atomic.shader_buffer_float32_atomics == vk::TRUE,
                },
                timestamp_period_ns: limits.timestamp_period,
                compute_timestamp_bits,
            })
        }
    }
}

impl Drop for VulkanInstance {
    fn drop(&mut self) {
        // SAFETY: every object created from the instance is owned by values that borrow or
        // outlive-check it (GpuContext owns its VulkanInstance and destroys its device first).
        unsafe { self.instance.destroy_instance(None) };
    }
}

/// One memory heap.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct MemoryHeap {
    pub size_bytes: u64,
    pub device_local: bool,
}

/// Float atomic support (VK_EXT_shader_atomic_float).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct FloatAtomics {
    /// The extension is offered at all.
    pub extension: bool,
    /// `atomicAdd(float)` on storage buffers: what gradient accumulation uses.
    pub buffer_f32_add: bool,
    /// `atomicAdd(float)` on shared memory.
    pub shared_f32_add: bool,
    /// Float atomic load/store/exchange on storage buffers.
    pub buffer_f32_exchange: bool,
}

/// What a device offers for compute.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceReport {
    /// Position in the loader's device list (`--device-index`).
    pub index: usize,
    pub name: String,
    /// `discrete`, `integrated`, `virtual`, `cpu` or `other`.
    pub device_type: String,
    pub driver_name: String,
    pub driver_info: String,
    /// Device API version, `major.minor.patch`.
    pub api_version: String,
    #[serde(skip)]
    pub api_version_raw: u32,
    pub memory_heaps: Vec<MemoryHeap>,
    pub max_storage_buffer_range_bytes: u64,
    pub max_compute_shared_memory_bytes: u32,
    /// Storage buffers one kernel may bind (Vulkan guarantees only 4).
    pub max_per_stage_storage_buffers: u32,
    /// Texels one texel-buffer view may address (Vulkan guarantees 65 536; lavapipe, Jetson and
    /// the Raspberry Pi 5 offer 2^27 or more): the rasterisers read primitive data through them.
    pub max_texel_buffer_elements: u64,
    pub max_compute_workgroup_invocations: u32,
    /// Largest local size per axis (Vulkan guarantees 128 × 128 × 64).
    #[serde(default)]
    pub max_compute_workgroup_size: [u32; 3],
    pub max_compute_workgroup_count_x: u32,
    pub subgroup_size: u32,
    /// Supported subgroup operation classes (`basic`, `arithmetic`, `ballot`, …).
    pub subgroup_operations: Vec<String>,
    /// Subgroup operations are available in compute shaders.
    pub subgroup_in_compute: bool,
    pub float_atomics: FloatAtomics,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Valid bits of timestamps on the best compute queue (0: no timestamp queries).
    pub compute_timestamp_bits: u32,
}

impl DeviceReport {
    /// Subgroup arithmetic (subgroupAdd …) is usable in compute shaders.
    pub fn has_subgroup_arithmetic(&self) -> bool {
        self.subgroup_in_compute && self.subgroup_operations.iter().any(|o| o == "arithmetic")
    }

    /// Preference for the default device: discrete > integrated > virtual > cpu > other.
    pub fn preference(&self) -> u32 {
        match self.device_type.as_str() {
            "discrete" => 4,
            "integrated" => 3,
            "virtual" => 2,
            "cpu" => 1,
            _ => 0,
        }
    }
}

fn device_type_name(t: vk::PhysicalDeviceType) -> &'static str {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => "discrete",
        vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated",
        vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual",
        vk::PhysicalDeviceType::CPU => "cpu",
        _ => "other",
    }
}

fn subgroup_operation_names(flags: vk::SubgroupFeatureFlags) -> Vec<String> {
    [
        (vk::SubgroupFeatureFlags::BASIC, "basic"),
        (vk::SubgroupFeatureFlags::VOTE, "vote"),
        (vk::SubgroupFeatureFlags::ARITHMETIC, "arithmetic"),
        (vk::SubgroupFeatureFlags::BALLOT, "ballot"),
        (vk::SubgroupFeatureFlags::SHUFFLE, "shuffle"),
        (
            vk::SubgroupFeatureFlags::SHUFFLE_RELATIVE,
            "shuffle_relative",
        ),
        (vk::SubgroupFeatureFlags::CLUSTERED, "clustered"),
        (vk::SubgroupFeatureFlags::QUAD, "quad"),
    ]
    .into_iter()
    .filter(|(f, _)| flags.contains(*f))
    .map(|(_, n)| n.to_owned())
    .collect()
}

/// `major.minor.patch` of a packed Vulkan version.
pub fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}
