//! Storage buffers: allocation through gpu-allocator (checked against the device's
//! storage-buffer range, counted in the context's current and peak use), upload, writes and
//! reads of host-visible buffers, release.

use std::sync::atomic::Ordering;

use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme, Allocator};

use super::GpuContext;
use crate::gpu::error::{GpuError, vk_err};

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

/// A storage buffer and its memory. Release it with [`GpuContext::destroy_buffer`].
#[derive(Debug)]
pub struct GpuBuffer {
    pub(super) raw: vk::Buffer,
    pub(super) allocation: Allocation,
    pub(super) size_bytes: u64,
    pub(super) name: String,
    pub(super) location: MemoryLocation,
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

impl GpuContext {
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
            .map_err(|source| GpuError::Allocation {
                name: name.to_owned(),
                bytes: size,
                source,
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

    fn lock_allocator(&self) -> Result<std::sync::MutexGuard<'_, Allocator>, GpuError> {
        self.allocator.lock().map_err(|_| GpuError::LockPoisoned {
            what: "GPU memory allocator",
        })
    }
}
