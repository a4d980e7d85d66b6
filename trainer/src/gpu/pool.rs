//! Reuse of released GPU buffers: the rasteriser's per-view buffers (primitive and band views,
//! key lists, planes …) go back to a [`BufferPool`] when a view is released and serve the next
//! view that fits, so a training step allocates nothing once the first steps have run.
//! Per-primitive buffers are created for the run's primitive budget
//! ([`BufferPool::set_reserve_prims`]), so density control growing the count up to the budget
//! never reallocates them, and the device memory a run needs is taken in its first steps.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

use super::context::{GpuBuffer, GpuContext, MemoryLocation};
use super::error::GpuError;

/// Released buffers kept for reuse at most; beyond that the smallest are destroyed.
const MAX_FREE: usize = 64;

/// Released buffers waiting for reuse, and the primitive count per-primitive buffers are sized
/// for. Release what it holds with [`BufferPool::destroy`].
#[derive(Debug, Default)]
pub struct BufferPool {
    free: Mutex<Vec<GpuBuffer>>,
    reserve_prims: AtomicUsize,
    /// Buffers created because no released one fitted.
    created: AtomicU64,
}

impl BufferPool {
    pub fn new() -> Self {
        Self::default()
    }

    /// Sizes per-primitive buffers created from now on for at least `prims` primitives (the
    /// run's budget).
    pub fn set_reserve_prims(&self, prims: usize) {
        self.reserve_prims.store(prims, Ordering::Relaxed);
    }

    /// The primitive count per-primitive buffers are created for: `n` or the reserve.
    pub fn prims_capacity(&self, n: usize) -> usize {
        n.max(self.reserve_prims.load(Ordering::Relaxed))
    }

    /// A buffer named `name` in `location` holding at least `bytes`: the smallest released one
    /// that fits, else a new one of `capacity.max(bytes)` bytes. Its contents are undefined.
    pub fn take(
        &self,
        ctx: &GpuContext,
        name: &str,
        bytes: u64,
        capacity: u64,
        location: MemoryLocation,
    ) -> Result<GpuBuffer, GpuError> {
        {
            let mut free = self.lock()?;
            let same = |b: &GpuBuffer| b.name() == name && b.location() == location;
            let fit = free
                .iter()
                .enumerate()
                .filter(|(_, b)| same(b) && b.size_bytes() >= bytes)
                .min_by_key(|(_, b)| b.size_bytes())
                .map(|(i, _)| i);
            if let Some(i) = fit {
                return Ok(free.swap_remove(i));
            }
            // Released buffers of this kind are all too small: they will not serve again.
            let mut i = 0;
            while i < free.len() {
                if same(&free[i]) {
                    ctx.destroy_buffer(free.swap_remove(i));
                } else {
                    i += 1;
                }
            }
        }
        let buffer = ctx.create_buffer(name, capacity.max(bytes), location)?;
        self.created.fetch_add(1, Ordering::Relaxed);
        Ok(buffer)
    }

    /// Buffers [`Self::take`] had to create so far (none once warm).
    pub fn created(&self) -> u64 {
        self.created.load(Ordering::Relaxed)
    }

    /// A host-visible buffer (see [`Self::take`]) whose first bytes hold `data`.
    pub fn upload<T: bytemuck::Pod>(
        &self,
        ctx: &GpuContext,
        name: &str,
        data: &[T],
        capacity: u64,
    ) -> Result<GpuBuffer, GpuError> {
        let bytes = std::mem::size_of_val(data) as u64;
        let mut buffer = self.take(ctx, name, bytes, capacity, MemoryLocation::Upload)?;
        if let Err(e) = ctx.write(&mut buffer, data) {
            self.give(ctx, buffer);
            return Err(e);
        }
        Ok(buffer)
    }

    /// Returns `buffer` for reuse (no pending work may use it).
    pub fn give(&self, ctx: &GpuContext, buffer: GpuBuffer) {
        let Ok(mut free) = self.lock() else {
            ctx.destroy_buffer(buffer);
            return;
        };
        free.push(buffer);
        if free.len() > MAX_FREE {
            free.sort_by_key(|b| std::cmp::Reverse(b.size_bytes()));
            for b in free.drain(MAX_FREE..) {
                ctx.destroy_buffer(b);
            }
        }
    }

    /// Destroys every released buffer.
    pub fn destroy(self, ctx: &GpuContext) {
        if let Ok(free) = self.free.into_inner() {
            for b in free {
                ctx.destroy_buffer(b);
            }
        }
    }

    fn lock(&self) -> Result<std::sync::MutexGuard<'_, Vec<GpuBuffer>>, GpuError> {
        self.free.lock().map_err(|_| GpuError::LockPoisoned {
            what: "GPU buffer pool",
        })
    }
}
