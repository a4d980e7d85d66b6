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
#[cfg(feature = "v4l")]
pub mod v4l2;

pub use error::CaptureError;
