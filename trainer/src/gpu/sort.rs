//! Stable GPU radix sort of 64-bit keys with `u32` payloads: the (tile, depth) key sort of the
//! rasteriser. Keys are `[low, high]` word pairs; `key_bits` limits the passes to the bits in use
//! (e.g. 12 tile bits + 32 depth bits = 44 bits: 12 passes of 4 bits, rounded up to even so the
//! result lands back in the caller's buffers).

use super::context::{ComputeKernel, GpuBuffer, GpuContext, MemoryLocation, Recorder};
use super::error::GpuError;
use super::scan::GpuScan;
use super::shaders::{self, push_u32s};

/// Items per workgroup block (RADIX_BLOCK in radix_common.glsl).
const BLOCK: usize = 128;
const BINS: usize = 16;

/// How many items a sort or a list kernel handles: `min(buffer[index], at_most)` (u32), read on
/// the GPU. `at_most` sizes the recorded work; the buffer may hold a count the GPU computed.
#[derive(Debug, Clone, Copy)]
pub struct ItemCount<'a> {
    pub at_most: usize,
    pub buffer: &'a GpuBuffer,
    pub index: u32,
}

/// A reusable GPU radix sort for up to `max_count` items.
#[derive(Debug)]
pub struct GpuRadixSort {
    count_kernel: ComputeKernel,
    scatter_kernel: ComputeKernel,
    scan: GpuScan,
    hist: GpuBuffer,
    keys_alt: GpuBuffer,
    values_alt: GpuBuffer,
    max_count: usize,
}

impl GpuRadixSort {
    pub fn new(ctx: &GpuContext, max_count: usize) -> Result<Self, GpuError> {
        let max_blocks = max_count.div_ceil(BLOCK).max(1);
        let count_kernel = shaders::build(ctx, "radix_count")?;
        let scatter_kernel = shaders::build(ctx, "radix_scatter");
        let scan =
            scatter_kernel.and_then(|s| GpuScan::new(ctx, max_blocks * BINS).map(|scan| (s, scan)));
        let (scatter_kernel, scan) = match scan {
            Ok(v) => v,
            Err(e) => {
                ctx.destroy_kernel(count_kernel);
                return Err(e);
            }
        };
        let buffers = (|| {
            let hist = ctx.create_buffer(
                "sort.hist",
                (max_blocks * BINS * 4) as u64,
                MemoryLocation::DeviceOnly,
            )?;
            let keys_alt = ctx.create_buffer(
                "sort.keys_alt",
                (max_count.max(1) * 8) as u64,
                MemoryLocation::DeviceOnly,
            );
            let keys_alt = match keys_alt {
                Ok(b) => b,
                Err(e) => {
                    ctx.destroy_buffer(hist);
                    return Err(e);
                }
            };
            match ctx.create_buffer(
                "sort.values_alt",
                (max_count.max(1) * 4) as u64,
                MemoryLocation::DeviceOnly,
            ) {
                Ok(values_alt) => Ok((hist, keys_alt, values_alt)),
                Err(e) => {
                    ctx.destroy_buffer(hist);
                    ctx.destroy_buffer(keys_alt);
                    Err(e)
                }
            }
        })();
        match buffers {
            Ok((hist, keys_alt, values_alt)) => Ok(Self {
                count_kernel,
                scatter_kernel,
                scan,
                hist,
                keys_alt,
                values_alt,
                max_count,
            }),
            Err(e) => {
                ctx.destroy_kernel(count_kernel);
                ctx.destroy_kernel(scatter_kernel);
                scan.destroy(ctx);
                Err(e)
            }
        }
    }

    /// Most items one call can sort.
    pub fn capacity(&self) -> usize {
        self.max_count
    }

    /// Records a stable sort of the first `count` (key, value) pairs by the low `key_bits` bits of
    /// the keys, in place (`keys`: `count` × `[u32; 2]` low/high words; `values`: `count` × u32).
    /// The count is read on the GPU ([`ItemCount`]), so it may come from earlier GPU work the
    /// host never read; the work recorded is sized for `count.at_most` items.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        keys: &GpuBuffer,
        values: &GpuBuffer,
        count: ItemCount<'_>,
        key_bits: u32,
    ) -> Result<(), GpuError> {
        let at_most = count.at_most;
        if at_most > self.max_count {
            return Err(GpuError::BufferRange {
                name: keys.name().to_owned(),
                requested_bytes: (at_most * 8) as u64,
                capacity_bytes: (self.max_count * 8) as u64,
            });
        }
        if at_most < 2 {
            return Ok(());
        }
        let passes = key_bits.clamp(1, 64).div_ceil(8) * 2; // even: ends in the caller's buffers
        let blocks = at_most.div_ceil(BLOCK);
        for pass in 0..passes {
            let shift = pass * 4;
            let (k_in, v_in, k_out, v_out) = if pass % 2 == 0 {
                (keys, values, &self.keys_alt, &self.values_alt)
            } else {
                (&self.keys_alt, &self.values_alt, keys, values)
            };
            let push = push_u32s(&[at_most as u32, shift, blocks as u32, count.index]);
            rec.dispatch(
                &self.count_kernel,
                &[k_in, &self.hist, count.buffer],
                &push,
                [blocks as u32, 1, 1],
            )?;
            rec.compute_barrier();
            self.scan.record(rec, &self.hist, blocks * BINS)?;
            rec.dispatch(
                &self.scatter_kernel,
                &[k_in, v_in, &self.hist, k_out, v_out, count.buffer],
                &push,
                [blocks as u32, 1, 1],
            )?;
            rec.compute_barrier();
        }
        Ok(())
    }

    /// Releases kernels and scratch buffers.
    pub fn destroy(self, ctx: &GpuContext) {
        ctx.destroy_kernel(self.count_kernel);
        ctx.destroy_kernel(self.scatter_kernel);
        self.scan.destroy(ctx);
        ctx.destroy_buffer(self.hist);
        ctx.destroy_buffer(self.keys_alt);
        ctx.destroy_buffer(self.values_alt);
    }
}
