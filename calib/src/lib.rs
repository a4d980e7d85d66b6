//! s3tir-calib: camera models, calibration files and (feature `opencv`) board detection.
//!
//! The camera model, rigid transforms and the file formats cameras travel in between stages
//! ([`model`]) build without OpenCV, so the trainer and the simulated rig share the exact model
//! calibration solves and one codec per format.
//! Conventions (frames, pixel-centre origin, units) are in `docs/CONVENTIONS.md`.
//!
//! The folders are the stages, in the order a calibration runs (`ARCHITECTURE.md` states which
//! may import which; `scripts/check-deps.sh` enforces it). Feature in brackets; none: always
//! built.
//! - `model`: what every stage shares — camera model, rigid transforms, `calibration.yaml`,
//!   the COLMAP codec.
//! - `detect` (`opencv`): images and sessions → board corners in canonical order.
//! - `solve` (`opencv`): corners → pair tests, initialisation, the joint solve, the result.
//! - `report` (`plots`): the result → report, `calibration.yaml` and exports (`opencv`);
//!   the plot canvas (`plots`).
//! - `poses` (`poses`): a recorded session → a posed thermal dataset (the poses stage).
//!
//! And beside them, used by several stages:
//! - `error`: the library's error type.
//! - `progress`: progress events of long runs (the library emits them); `progress::bars`
//!   (`poses`): the indicatif adapter that draws them (binaries only).
//! - `tags` (`tags`): tag36h11 AprilTag detection and code tables (board tags and the poses
//!   stage's fiducials).
//! - `synth` (`opencv`): synthetic board sets with known truth (tests, benchmark).
//! - `bench` (`opencv`): `s3tir-calib bench`, against OpenCV in the same process.

#[cfg(feature = "opencv")]
pub mod bench;
#[cfg(feature = "opencv")]
pub mod detect;
pub mod error;
pub mod model;
#[cfg(feature = "poses")]
pub mod poses;
pub mod progress;
#[cfg(feature = "plots")]
pub mod report;
#[cfg(feature = "opencv")]
pub mod solve;
#[cfg(feature = "opencv")]
pub mod synth;
#[cfg(feature = "tags")]
pub mod tags;

pub use error::CalibError;
pub use model::camera::{BrownConrady, CameraModel, Intrinsics};
pub use model::geometry::Rigid3;
