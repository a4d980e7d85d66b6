//! Exclusive prefix sum of `u32` on the GPU (tile binning and radix-sort offsets build on it).
//!
//! Level 1 (`scan_blocks`) scans blocks of 2048 values in place and collects block totals; the
//! totals are scanned recursively and added back (`scan_add`). All levels' scratch buffers are
//! allocated once for a maximum count, so recording a scan allocates nothing.

use super::context::{ComputeKernel, GpuBuffer, GpuContext, MemoryLocation, Recorder};
use super::error::GpuError;
use super::shaders::{self, push_u32s};

/// Values one `scan_blocks` workgroup scans.
pub const SCAN_BLOCK: usize = 2048;
const ADD_WG: usize = 256;

/// A reusable GPU exclusive scan for up to `max_count` values.
#[derive(Debug)]
pub struct GpuScan {
    blocks: ComputeKernel,
    add: ComputeKernel,
    /// Block-sum buffers, one per level (level 0 holds the sums of the input's blocks).
    levels: Vec<GpuBuffer>,
    max_count: usize,
}

impl GpuScan {
    pub fn new(ctx: &GpuContext, max_count: usize) -> Result<Self, GpuError> {
        let blocks = shaders::build(ctx, "scan_blocks")?;
        let add = match shaders::build(ctx, "scan_add") {
            Ok(k) => k,
            Err(e) => {
                ctx.destroy_kernel(blocks);
                return Err(e);
            }
        };
        let mut scan = Self {
            blocks,
            add,
            levels: Vec::new(),
            max_count,
        };
        let mut count = max_count;
        loop {
            let sums = count.div_ceil(SCAN_BLOCK).max(1);
            match ctx.create_buffer(
                &format!("scan.level{}", scan.levels.len()),
                (sums * 4) as u64,
                MemoryLocation::DeviceOnly,
            ) {
                Ok(b) => scan.levels.push(b),
                Err(e) => {
                    scan.destroy(ctx);
                    return Err(e);
                }
            }
            if sums <= 1 {
                break;
            }
            count = sums;
        }
        Ok(scan)
    }

    /// Most values one call can scan.
    pub fn capacity(&self) -> usize {
        self.max_count
    }

    /// Records an exclusive scan of the first `count` values of `data`, in place.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        data: &GpuBuffer,
        count: usize,
    ) -> Result<(), GpuError> {
        if count > self.max_count {
            return Err(GpuError::BufferRange {
                name: data.name().to_owned(),
                requested_bytes: (count * 4) as u64,
                capacity_bytes: (self.max_count * 4) as u64,
            });
        }
        self.record_level(rec, data, count, 0)
    }

    fn record_level(
        &self,
        rec: &mut Recorder<'_>,
        data: &GpuBuffer,
        count: usize,
        level: usize,
    ) -> Result<(), GpuError> {
        if count == 0 {
            return Ok(());
        }
        let sums = self
            .levels
            .get(level)
            .ok_or_else(|| GpuError::BufferRange {
                name: format!("scan.level{level}"),
                requested_bytes: 4,
                capacity_bytes: 0,
            })?;
        let groups = count.div_ceil(SCAN_BLOCK);
        rec.dispatch(
            &self.blocks,
            &[data, sums],
            &push_u32s(&[count as u32]),
            [groups as u32, 1, 1],
        )?;
        rec.compute_barrier();
        if groups > 1 {
            self.record_level(rec, sums, groups, level + 1)?;
            rec.dispatch(
                &self.add,
                &[data, sums],
                &push_u32s(&[count as u32]),
                [count.div_ceil(ADD_WG) as u32, 1, 1],
            )?;
            rec.compute_barrier();
        }
        Ok(())
    }

    /// Releases the kernels and scratch buffers.
    pub fn destroy(self, ctx: &GpuContext) {
        ctx.destroy_kernel(self.blocks);
        ctx.destroy_kernel(self.add);
        for b in self.levels {
            ctx.destroy_buffer(b);
        }
    }
}
