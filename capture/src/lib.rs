//! s3tir-capture: the bottom layer of s3tir.
//!
//! It owns what every other crate agrees on about data coming off a rig:
//! - [`frame`]: the frame model (raw 16-bit thermal data kept untouched, RGB kept as delivered),
//! - [`device`]: V4L2-style pixel formats, device descriptions and the role guess
//!   (thermal vs RGB) used by `s3tir-capture list`,
//! - [`v4l2`] (feature `v4l`): enumeration of real V4L2 devices.
//!
//! Conventions (timestamps, units) are in `docs/CONVENTIONS.md`.

pub mod device;
pub mod error;
pub mod frame;
/// Boson FSLP serial codec (shared with the simulated rig).
pub mod fslp;
/// Rig controller serial protocol codec (shared with the simulated rig).
pub mod rig_protocol;
/// V4L2-shaped frames over a local socket (simulated rig -> capture).
pub mod simwire;
#[cfg(feature = "v4l")]
pub mod v4l2;

pub use error::CaptureError;
/// Recorder throughput benchmark (`s3tir-capture bench`).
pub mod bench;
/// Rig-controller clock → camera clock: robust linear fit over matched trigger pulses.
pub mod clock_sync;
/// The capture daemon (tokio, bounded queue, reconnect, clean shutdown).
pub mod daemon;
/// RGB cameras through nokhwa (feature `nokhwa`; format mapping always built and tested).
pub mod nokhwa_backend;
/// Thermal↔RGB pairing, drop detection, sync statistics.
pub mod pairing;
/// Parse → drop detection → pairing: the path of every frame, live or replayed.
pub mod pipeline;
/// Serial clients: FLIR Boson (FSLP) and rig controller.
pub mod serial;
/// MCAP sessions: writer and crash-tolerant reader.
pub mod session;
/// Simulated-rig backend (`--device sim`) and an in-process fake rig.
pub mod sim_backend;
/// Deterministic synthetic device buffers (bench load, test fakes).
pub mod synth;
/// Lepton telemetry rows (160×122 mode) decoding.
pub mod telemetry;
/// `info`, `replay`, `export` over recorded sessions.
pub mod tools;
/// V4L2 format negotiation and buffer interpretation (pure; tested without a camera).
pub mod v4l2_negotiate;
/// V4L2 mmap streaming with poll + timeout (feature `v4l`).
#[cfg(feature = "v4l")]
pub mod v4l2_stream;
