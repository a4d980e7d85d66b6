//! One-shot submissions: a command buffer recorded by a [`Recorder`], submitted and waited
//! for with a bounded fence wait (a hung device is an error, not a wait for ever), with
//! per-dispatch timestamp queries when profiled.

use std::sync::atomic::Ordering;

use ash::vk;

use super::{GpuContext, Recorder};
use crate::gpu::error::{GpuError, vk_err};

/// Longest wait for one submission before the device is declared hung. Far above the
/// longest submission seen (a whole training step at 640×512 on lavapipe takes seconds).
pub const SUBMIT_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(300);

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

impl GpuContext {
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

    // Why this stays long: it is one `unsafe` block in which every exit (each Vulkan error,
    // the bounded wait's timeout) releases exactly the objects created so far — pools, views,
    // the command buffer, the fence — and a hung submission leaks them on purpose. Split into
    // functions, each would need the others' handles and the release rules would be spread.
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
}

/// Most dispatches one profiled submission times; later ones run untimed.
pub const MAX_TIMED_DISPATCHES: u32 = 1024;

/// GPU time of one dispatch, from timestamp queries.
#[derive(Debug, Clone, PartialEq)]
pub struct KernelTiming {
    pub kernel: String,
    pub duration_ns: f64,
}

#[cfg(test)]
mod tests {
    //! Proves: a fence wait gives up after its limit with `SubmitTimeout` (a hung device is an
    //! error, not a wait for ever) and passes other Vulkan errors through. The real submission
    //! path is tested on lavapipe in `tests/gpu_*.rs`.
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
}
