//! One Vulkan device opened for compute: the [`GpuContext`] (device, queue, command pool,
//! allocator with current and peak use, traffic counters), what it lets kernels use
//! ([`Capabilities`]) and its release. Each job of the context is a file (private modules,
//! their items re-exported here):
//!
//! - `open`: choosing and opening the device, the checks before anything is created,
//! - `buffers`: storage buffers (allocation, upload, reads and writes, release),
//! - `kernels`: compute pipelines with their descriptor layouts and push constants,
//! - `submit`: one-shot submissions with bounded fence waits and timestamp queries,
//! - `recorder`: the commands recorded into a submission (dispatches, copies, barriers).

mod buffers;
mod kernels;
mod open;
mod recorder;
mod submit;

use std::mem::ManuallyDrop;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use ash::vk;
use gpu_allocator::vulkan::Allocator;

use super::devices::{DeviceReport, VulkanInstance};

pub use buffers::{GpuBuffer, MemoryLocation};
pub use kernels::{Binding, ComputeKernel, TexelFormat};
pub use open::{
    ContextOptions, DeviceChoice, WORKGROUP_INVOCATIONS_USED, WORKGROUP_SIZE_USED,
    check_workgroup_limits,
};
pub use recorder::Recorder;
pub use submit::{KernelTiming, MAX_TIMED_DISPATCHES, SUBMIT_TIMEOUT, wait_bounded};

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
