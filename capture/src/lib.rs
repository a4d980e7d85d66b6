//! s3tir-capture: the bottom layer of s3tir.
//!
//! It owns what every other crate agrees on about data coming off a rig. Modules by layer
//! (features in `README.md`, "Features"):
//!
//! Leaf types, always built (no tokio, MCAP, serial port or V4L2):
//! - [`frame`]: the frame model (raw 16-bit thermal data kept untouched, RGB kept as delivered),
//! - [`device`]: V4L2-style pixel formats, device descriptions and the role guess
//!   (thermal vs RGB) used by `s3tir-capture list`,
//! - [`telemetry`]: Lepton telemetry rows (160×122 mode) decoding,
//! - [`image_meta`]: image files' metadata (EXIF, XMP: capture time, GPS, altitudes, gimbal
//!   and flight angles), and [`jpeg_segments`], the one walker of a JPEG's segments,
//! - [`radiometric`]: radiometric files of other cameras (FLIR's FFF and radiometric JPEGs) to
//!   raw words, the camera's calibration and kelvin,
//! - [`error`]: the error type ([`CaptureError`]) and [`Chain`], how any error is printed (an
//!   error's message is its own level, its cause comes from `source()`),
//! - [`skip`]: how the workspace's tests skip what a machine lacks (and fail where it must not),
//! - [`wire`]: the wire codecs shared with the simulated rig (FSLP, rig controller protocol,
//!   simwire); its serial clients need feature `rig`.
//!
//! Feature `session`:
//! - [`session`]: MCAP sessions (records, writer, crash-tolerant reader) and the frame path
//!   that fills them (pairing, clock sync, pipeline).
//!
//! Feature `rig` (the recorder and its binary):
//! - [`backend`]: device backends behind one `FrameSource` trait (V4L2, nokhwa, simulated rig,
//!   synthetic buffers),
//! - [`daemon`]: the capture daemon (tokio, bounded queue, reconnect, clean shutdown when its
//!   caller sets the stop flag; reports [`daemon::DaemonEvent`]s, draws nothing),
//! - [`tools`]: `info`, `replay`, `export` over recorded sessions,
//! - [`bench`](mod@bench): recorder throughput benchmark (`s3tir-capture bench`).
//!
//! Conventions (timestamps, units) are in `docs/CONVENTIONS.md`.

// The module list above links every module; in builds that leave feature-gated modules out
// (`--no-default-features`) those links have nothing to point at.
#![cfg_attr(not(feature = "rig"), allow(rustdoc::broken_intra_doc_links))]

pub mod device;
pub mod error;
pub mod frame;
pub mod image_meta;
pub mod jpeg_segments;
pub mod radiometric;
pub mod skip;
pub mod telemetry;
pub mod wire;

#[cfg(feature = "session")]
pub mod session;

#[cfg(feature = "rig")]
pub mod backend;
#[cfg(feature = "rig")]
pub mod bench;
#[cfg(feature = "rig")]
pub mod daemon;
#[cfg(feature = "rig")]
pub mod tools;

pub use error::{CaptureError, Chain};
