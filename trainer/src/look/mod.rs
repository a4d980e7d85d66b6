//! What a person looks at: a run's thermal images drawn through a palette with their range,
//! figures with colour bars in kelvin and °C, and the run report.
//!
//! - [`image`]: a scalar plane as an 8-bit palette PNG whose range is in the file (PNG `tEXt`),
//!   and reading that range back; the renders' and G-buffers' readable copies.
//! - [`figure`]: rows of palette panels, each with its colour bar (kelvin and °C for
//!   radiometric runs, the normalised unit otherwise, said so).
//! - [`flight`]: novel views along a path (the held-out views, an orbit, a spiral, a file) as
//!   palette frames with a colour bar and a video (`s3tir-train render`).
//! - [`report`]: `report.html` (and `report.md`) of a run folder — settings and outcome, the
//!   held-out views recorded | rendered | error, error against time, G-buffers, density and
//!   band statistics, the per-view response — through the calibration report's page
//!   (`s3tir_calib::report::page`) and plot font, so both reports look alike.
//! - [`view`]: `s3tir-train view` — a local web viewer of the run's thermal mesh (orbit,
//!   palette and range, the temperature of a picked point), served on 127.0.0.1.
//!
//! The 16-bit renders and `.npy` G-buffers stay the data; everything here is drawn from them
//! (and from the dataset's recorded frames), so `s3tir-train report RUN` redraws an older run.

pub mod figure;
pub mod flight;
pub mod image;
pub mod report;
pub mod view;

use std::path::PathBuf;

/// Why a picture or the report could not be written.
#[derive(Debug, thiserror::Error)]
pub enum LookError {
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error(transparent)]
    Image(#[from] image::ImageError),
    #[error("drawing {path}")]
    Plot {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error(transparent)]
    Report(#[from] crate::report::ReportError),
    #[error(transparent)]
    Train(#[from] Box<crate::train::TrainError>),
}

impl From<crate::train::TrainError> for LookError {
    fn from(e: crate::train::TrainError) -> Self {
        Self::Train(Box::new(e))
    }
}
