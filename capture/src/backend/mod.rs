//! Device backends (feature `rig`): everything that delivers device buffers ([`RawFrame`])
//! behind the one [`FrameSource`] trait the daemon reads.
//!
//! - [`v4l2`] (feature `v4l`): enumeration of real V4L2 devices,
//! - [`v4l2_negotiate`]: V4L2 format negotiation and buffer interpretation (pure; tested
//!   without a camera); [`v4l2_stream`] (feature `v4l`) streams with it (open, `VIDIOC_S_FMT`,
//!   mmap, poll),
//! - [`nokhwa_backend`]: RGB cameras through nokhwa (feature `nokhwa`; format mapping always
//!   built and tested),
//! - [`sim_backend`]: the simulated rig's socket (`--device sim`) and an in-process fake rig,
//! - [`synth`]: deterministic synthetic device buffers (bench load, test fakes),
//! - [`stamp`]: the host clock reads that stamp frames.

use crate::error::CaptureError;
use crate::frame::RawFrame;

pub mod nokhwa_backend;
pub mod sim_backend;
pub mod stamp;
pub mod synth;
#[cfg(feature = "v4l")]
pub mod v4l2;
pub mod v4l2_negotiate;
#[cfg(feature = "v4l")]
pub mod v4l2_stream;

/// A source of device buffers: a V4L2 node, the simulated rig's socket, or a test fake. The
/// daemon runs one reader thread per source and reopens it through its factory when it fails.
pub trait FrameSource: Send {
    /// Name used in logs and errors (device path, socket path).
    fn name(&self) -> &str;
    /// Blocks for the next buffer, at most `timeout`: `Ok(None)` on timeout. An error means
    /// the device is gone (unplugged, rig stopped); the caller reopens it.
    fn next_frame(
        &mut self,
        timeout: std::time::Duration,
    ) -> Result<Option<RawFrame>, CaptureError>;
}
