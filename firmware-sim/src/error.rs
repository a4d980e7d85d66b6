//! Errors of the simulated rig. Every variant names the file, profile or parameter it is about,
//! and keeps the underlying error (if any) as its source.

use std::path::PathBuf;

/// Errors raised by the simulator library.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("unknown profile {name:?}; known: {known}")]
    UnknownProfile { name: String, known: &'static str },
    #[error("{path}: {what}")]
    Io {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// Something could not be encoded and no library error says why (a validation).
    #[error("encoding {what}: {reason}")]
    Encode { what: &'static str, reason: String },
    /// An image file (PNG) could not be encoded or written (boxed: the error is large).
    #[error("{path}: writing {what}")]
    Image {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: Box<image::ImageError>,
    },
    /// An in-memory frame (JPEG) could not be encoded.
    #[error("encoding {what}")]
    Frame {
        what: &'static str,
        #[source]
        source: Box<image::ImageError>,
    },
    /// A JSON document could not be serialised.
    #[error("encoding {what}")]
    Json {
        what: &'static str,
        #[source]
        source: serde_json::Error,
    },
    /// The COLMAP text model could not be written.
    #[error("writing the COLMAP model")]
    Colmap {
        #[source]
        source: Box<s3tir_calib::model::colmap::ColmapError>,
    },
    #[error("invalid parameter {parameter} = {value}: {why}")]
    InvalidParameter {
        parameter: &'static str,
        value: String,
        why: &'static str,
    },
    #[error("could not place view {view}: no board pose found after {attempts} attempts")]
    NoPose { view: usize, attempts: usize },
}
