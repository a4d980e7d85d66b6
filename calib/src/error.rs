//! Errors of the calibration layer. Each variant names the file or quantity it is about.

use std::path::PathBuf;

/// Errors raised by the calibration library.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// An image that cannot be used for detection (too small, a buffer of the wrong size, not
    /// in the session): a validation, no underlying error.
    #[error("image {path}: {reason}")]
    Image { path: PathBuf, reason: String },
    /// An image file could not be read or decoded.
    #[cfg(feature = "tags")]
    #[error("image {path}")]
    ImageFile {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    /// A recorded frame could not be decoded (the session's MJPEG payload).
    #[error("image {path}")]
    Frame {
        path: PathBuf,
        #[source]
        source: s3tir_capture::CaptureError,
    },
    /// OpenCV reported an error during `operation`.
    #[cfg(feature = "opencv")]
    #[error("OpenCV {operation}")]
    OpenCv {
        operation: &'static str,
        #[source]
        source: opencv::Error,
    },
    /// The AprilTag detector failed (the error names the image).
    #[cfg(feature = "tags")]
    #[error("AprilTag detection")]
    Tags {
        #[source]
        source: crate::tags::TagError,
    },
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
    /// `board.toml` describes a board that cannot be used (a validation).
    #[error("board description {path}: {reason}")]
    BoardFile { path: PathBuf, reason: String },
    /// `board.toml` missing or unreadable.
    #[error("board description {path}")]
    BoardFileRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// `board.toml` is not valid TOML or lacks a field.
    #[cfg(feature = "opencv")]
    #[error("board description {path}")]
    BoardFileSyntax {
        path: PathBuf,
        #[source]
        source: toml::de::Error,
    },
    /// The board folder is not a folder.
    #[error("board folder {path}: {reason}")]
    BoardFolder { path: PathBuf, reason: String },
    /// The board folder cannot be listed.
    #[error("board folder {path}")]
    BoardFolderRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A recorded session was given without the board description it needs.
    #[error(
        "{path}: a recorded session (.mcap) does not carry the board geometry: pass --board board.toml ([board] inner_corners, square_mm)"
    )]
    SessionNeedsBoard { path: PathBuf },
    /// A recorded session could not be read (capture's error names the session, so this
    /// level adds nothing to its message).
    #[error(transparent)]
    Session { source: s3tir_capture::CaptureError },
    /// Nothing in the input can be calibrated.
    #[error("{path}: nothing usable to calibrate: {reason}")]
    NothingUsable { path: PathBuf, reason: String },
    /// An output could not be written and no library error says why.
    #[error("writing {path}: {reason}")]
    Output { path: PathBuf, reason: String },
    /// An output file could not be encoded or written (an I/O, JSON or image error).
    #[error("writing {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Maps an OpenCV error into [`CalibError::OpenCv`] naming the `operation` (for `map_err`).
#[cfg(feature = "opencv")]
pub(crate) fn cv(operation: &'static str) -> impl FnOnce(opencv::Error) -> CalibError {
    move |source| CalibError::OpenCv { operation, source }
}
