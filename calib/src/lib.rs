//! s3tir-calib: camera models, calibration files and (feature `opencv`) board detection.
//!
//! The camera model ([`camera`]), rigid transforms ([`geometry`]) and the file formats cameras
//! travel in between stages ([`colmap`], [`calfile`]) build without OpenCV, so the trainer and the
//! simulated rig share the exact model calibration solves and one codec per format.
//! Conventions (frames, pixel-centre origin, units) are in `docs/CONVENTIONS.md`.

#[cfg(feature = "opencv")]
pub mod bench;
#[cfg(feature = "opencv")]
pub mod board;
pub mod calfile;
pub mod camera;
pub mod colmap;
#[cfg(feature = "opencv")]
pub mod detect;
pub mod error;
#[cfg(feature = "opencv")]
pub mod export;
#[cfg(feature = "opencv")]
pub mod frontend;
pub mod geometry;
#[cfg(feature = "opencv")]
pub mod pairs;
#[cfg(feature = "opencv")]
pub mod pipeline;
#[cfg(feature = "poses")]
pub mod poses;
#[cfg(feature = "opencv")]
pub mod report;
#[cfg(feature = "opencv")]
pub mod saddle;
#[cfg(feature = "opencv")]
pub mod schur;
#[cfg(feature = "opencv")]
pub mod session;
#[cfg(feature = "opencv")]
pub mod solve;
#[cfg(feature = "opencv")]
pub mod synth;
#[cfg(feature = "opencv")]
pub mod tagboard;
#[cfg(feature = "tags")]
pub mod tags;
#[cfg(feature = "opencv")]
pub mod views;

pub use camera::{BrownConrady, CameraModel, Intrinsics};
pub use error::CalibError;
pub use geometry::Rigid3;
