//! Solving (feature `opencv`): detected corners → a calibration. Imports [`crate::model`],
//! [`crate::detect`], [`crate::progress`] and [`crate::error`]; never [`crate::report`] or
//! the poses stage.
//!
//! - [`pairs`]: pair-consistency tests (transfer consensus, residual).
//! - [`lm`]: the joint Levenberg–Marquardt over both cameras and every pose.
//! - [`schur`]: block-sparse normal equations and their Schur-complement solve.
//! - [`pipeline`]: detections → initialisation → mono and joint solves → result.

pub mod lm;
pub mod pairs;
pub mod pipeline;
pub mod schur;
