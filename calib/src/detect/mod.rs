//! Detection (feature `opencv`): board images and recorded sessions → board corners in
//! canonical order, per image and over a whole folder or session. Imports [`crate::model`],
//! [`crate::tags`], [`crate::progress`] and [`crate::error`]; never the later stages.
//!
//! - [`board`]: `board.toml`, the board's geometry and tag layout, the board folder.
//! - [`scalar`]: image files → scalar images (palette inversion, percentile stretch).
//! - [`chessboard`]: OpenCV's chessboard detectors as a user calls them.
//! - [`homography`]: plane → image homography and the planar-fit RMS.
//! - [`saddle`]: the blurred-saddle sub-pixel corner fit.
//! - [`tagboard`]: AprilTags on the board: identity, order, partial boards, masking.
//! - [`frontend`]: board detection in one image, in canonical corner order.
//! - [`session`]: a recorded session as calibration input (its views).
//! - [`views`]: detection over a board folder or session, thermal order fixed to RGB.

pub mod board;
pub mod chessboard;
pub mod frontend;
pub mod homography;
pub mod saddle;
pub mod scalar;
pub mod session;
pub mod tagboard;
pub mod views;
