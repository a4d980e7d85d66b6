//! s3tir-calib: camera models, calibration files and (feature `opencv`) board detection.
//!
//! The camera model ([`camera`]) and rigid transforms ([`geometry`]) build without OpenCV so
//! the trainer and the simulated rig share the exact model calibration solves.
//! Conventions (frames, pixel-centre origin, units) are in `docs/CONVENTIONS.md`.

pub mod camera;
#[cfg(feature = "opencv")]
pub mod detect;
pub mod error;
pub mod geometry;

pub use camera::{BrownConrady, CameraModel, Intrinsics};
pub use error::CalibError;
pub use geometry::Rigid3;
