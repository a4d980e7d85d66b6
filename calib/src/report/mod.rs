//! Outputs of a calibration, for people and for other tools (feature `plots`; the calibration
//! outputs with `opencv`). Imports [`crate::model`], [`crate::detect`], [`crate::solve`] and
//! [`crate::error`]; never the poses stage.
//!
//! - [`plot`] (`plots`): PNG plots with the bundled font (also the trainer's plots).
//! - [`page`] (`plots`): a report page written once, rendered as Markdown and as one
//!   self-contained HTML page (figures embedded).
//! - [`figures`] (`opencv`): the calibration report's PNG figures.
//! - [`document`] (`opencv`): `--report DIR` (the page's sections, `iterations.csv`).
//! - [`export`] (`opencv`): summary JSON, `calibration.yaml`, OpenCV/Kalibr/COLMAP/ROS exports.

#[cfg(feature = "opencv")]
pub mod document;
#[cfg(feature = "opencv")]
pub mod export;
#[cfg(feature = "opencv")]
pub mod figures;
pub mod page;
pub mod plot;
