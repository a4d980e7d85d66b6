//! The jobs of `s3tir-calib` that need more than a function of `main.rs`, one module each
//! (their options and what they run); `main.rs` holds the clap top level, the logging set-up,
//! the calibration run itself and the dispatch.
//!
//! - [`poses`]: `poses`: a recorded session → a posed dataset, through the library's
//!   [`s3tir_calib::poses`] with the board finder, progress bars and the summary.

pub mod poses;
