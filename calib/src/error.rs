//! Errors of the calibration layer. Each variant names the file or quantity it is about.

use std::path::PathBuf;

/// Errors raised by the calibration library.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// An image file could not be read or decoded.
    #[error("image {path}: {reason}")]
    Image { path: PathBuf, reason: String },
    /// OpenCV reported an error during `operation`.
    #[cfg(feature = "opencv")]
    #[error("OpenCV {operation}: {source}")]
    OpenCv {
        operation: &'static str,
        #[source]
        source: opencv::Error,
    },
    /// The AprilTag detector failed (the caller names the image).
    #[error("AprilTag detection: {reason}")]
    Tags { reason: String },
    /// A board description that cannot be detected (fewer than 2x2 inner corners).
    #[error("board with {cols}x{rows} inner corners: at least 2x2 are needed")]
    BoardTooSmall { cols: u32, rows: u32 },
    /// A camera model parameter that is not finite or not positive where it must be.
    #[error("camera model: {parameter} = {value} is not valid ({why})")]
    InvalidModel {
        parameter: &'static str,
        value: f64,
        why: &'static str,
    },
    /// `board.toml` missing, unreadable or invalid.
    #[error("board description {path}: {reason}")]
    BoardFile { path: PathBuf, reason: String },
    /// The board folder cannot be listed.
    #[error("board folder {path}: {reason}")]
    BoardFolder { path: PathBuf, reason: String },
    /// A recorded session was given without the board description it needs.
    #[error(
        "{path}: a recorded session (.mcap) does not carry the board geometry: pass --board board.toml ([board] inner_corners, square_mm)"
    )]
    SessionNeedsBoard { path: PathBuf },
    /// A recorded session could not be read.
    #[error("session {path}: {reason}")]
    Session { path: PathBuf, reason: String },
    /// Nothing in the input can be calibrated.
    #[error("{path}: nothing usable to calibrate: {reason}")]
    NothingUsable { path: PathBuf, reason: String },
    /// An output file could not be written.
    #[error("writing {path}: {reason}")]
    Output { path: PathBuf, reason: String },
}
