//! Outputs of a calibration, for people and for other tools (feature `plots`; the calibration
//! outputs with `opencv`). Imports [`crate::model`], [`crate::detect`], [`crate::solve`] and
//! [`crate::error`]; never the poses stage.
//!
//! - [`plot`] (`plots`): PNG plots with the bundled font (also the trainer's plots).
//! - [`document`] (`opencv`): `--report DIR` (markdown, HTML, plots).
//! - [`export`] (`opencv`): summary JSON, `calibration.yaml`, OpenCV/Kalibr/COLMAP/ROS exports.

#[cfg(feature = "opencv")]
pub mod document;
#[cfg(feature = "opencv")]
pub mod export;
pub mod plot;
