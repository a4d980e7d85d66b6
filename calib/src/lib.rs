//! s3tir-calib: camera models, calibration files and (feature `opencv`) board detection.
//!
//! The camera model ([`camera`]), rigid transforms ([`geometry`]) and the file formats cameras
//! travel in between stages ([`colmap`], [`calfile`]) build without OpenCV, so the trainer and the
//! simulated rig share the exact model calibration solves and one codec per format.
//! Conventions (frames, pixel-centre origin, units) are in `docs/CONVENTIONS.md`.
//!
//! Modules (feature in brackets; none: always built):
//! - `camera`: pinhole + Brown–Conrady camera model.
//! - `geometry`: rigid transforms (`b_from_a`).
//! - `calfile`: `calibration.yaml` reader and model-only writer.
//! - `colmap`: the workspace's COLMAP sparse-model codec (text and binary).
//! - `error`: the library's error type.
//! - `progress`: progress events of long runs (the library emits them, binaries draw them).
//! - `progress_bars` (`poses`): the indicatif adapter that draws them (binaries only).
//! - `tags` (`tags`): tag36h11 AprilTag detection and code tables.
//! - `poses` (`poses`): a recorded session → a posed thermal dataset (the poses stage).
//! - `plot` (`plots`): PNG plots with the bundled font.
//! - `board` (`opencv`): `board.toml`, the board's geometry and tag layout, the board folder.
//! - `scalar` (`opencv`): image files → scalar images (palette inversion, percentile stretch).
//! - `detect` (`opencv`): OpenCV's chessboard detectors as a user calls them.
//! - `homography` (`opencv`): plane → image homography and the planar-fit RMS.
//! - `saddle` (`opencv`): the blurred-saddle sub-pixel corner fit.
//! - `tagboard` (`opencv`): AprilTags on the board: identity, order, partial boards, masking.
//! - `frontend` (`opencv`): board detection in one image, in canonical corner order.
//! - `session` (`opencv`): a recorded session as calibration input (its views).
//! - `views` (`opencv`): detection over a board folder or session, thermal order fixed to RGB.
//! - `pairs` (`opencv`): pair-consistency tests (transfer consensus, residual).
//! - `solve` (`opencv`): the joint Levenberg–Marquardt over both cameras and every pose.
//! - `schur` (`opencv`): block-sparse normal equations and their Schur-complement solve.
//! - `pipeline` (`opencv`): detections → initialisation → mono and joint solves → result.
//! - `export` (`opencv`): summary JSON, `calibration.yaml`, OpenCV/Kalibr/COLMAP/ROS exports.
//! - `report` (`opencv`): `--report DIR` (markdown, HTML, plots).
//! - `synth` (`opencv`): synthetic board sets with known truth (tests, benchmark).
//! - `bench` (`opencv`): `s3tir-calib bench`, against OpenCV in the same process.

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
pub mod homography;
#[cfg(feature = "opencv")]
pub mod pairs;
#[cfg(feature = "opencv")]
pub mod pipeline;
#[cfg(feature = "plots")]
pub mod plot;
#[cfg(feature = "poses")]
pub mod poses;
pub mod progress;
#[cfg(feature = "poses")]
pub mod progress_bars;
#[cfg(feature = "opencv")]
pub mod report;
#[cfg(feature = "opencv")]
pub mod saddle;
#[cfg(feature = "opencv")]
pub mod scalar;
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
