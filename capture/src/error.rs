//! Errors of the capture layer. Every variant names the device or file it is about.

use std::path::PathBuf;

/// Errors raised by the capture library.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A device node could not be opened or queried.
    #[error("device {path}: {what}: {source}")]
    Device {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// A buffer does not have the size its format says it must have.
    #[error("{device}: frame buffer of {actual_bytes} bytes, expected {expected_bytes} for {width}x{height} {fourcc}")]
    BufferSize {
        device: String,
        fourcc: String,
        width: u32,
        height: u32,
        expected_bytes: usize,
        actual_bytes: usize,
    },
    /// A fourcc that is not four ASCII bytes.
    #[error("invalid fourcc {text:?}: must be exactly four ASCII characters")]
    InvalidFourcc { text: String },
}
