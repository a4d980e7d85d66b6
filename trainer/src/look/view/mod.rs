//! `s3tir-train view RUN`: a local web viewer of a run's thermal mesh — orbit it, switch palette
//! and range, hover or click to read a surface point's temperature in K and °C.
//!
//! - [`assets`]: the page (shipped inside the binary) and the vendored WebGL renderer (three.js
//!   from the npm registry, installed once by `scripts/install-viewer.py`, checksummed here).
//! - [`scene`]: what the page is told about the run (`/api/scene.json`): its meshes and their
//!   ranges, the unit (kelvin, or the normalised unit of a non-radiometric run), the palettes
//!   (calib's, one owner), the first held-out camera to start from.
//! - [`http`]: the server — a small blocking HTTP/1.1 server (`tiny_http`) on 127.0.0.1 by
//!   default that serves the page, the renderer and the run folder's files only: no path out of
//!   the run folder (`..`, encoded or not, symlinks), no directory listing, GET and HEAD only,
//!   and only requests addressed to an IP address, `localhost` or an allowed name (DNS
//!   rebinding). It stops when the caller's flag is set (Ctrl-C in the CLI).
//!
//! The page reads the mesh PLY as written by `s3tir-train mesh` (its `kelvin` vertex property)
//! with three.js's PLY loader: the mesh file has one writer (`mesh::plyio`), and the viewer adds
//! no format of its own.

pub mod assets;
pub mod http;
pub mod scene;

use std::path::PathBuf;

/// Why the viewer could not start or serve.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "the viewer's renderer (three.js {version}) is not installed in {dir}: {reason} \
         (run scripts/install-viewer.py, or scripts/install-deps.sh; \
         $S3TIR_VIEWER_ASSETS names another folder)"
    )]
    Assets {
        dir: PathBuf,
        version: &'static str,
        reason: String,
    },
    #[error("{path}: {reason}")]
    Run { path: PathBuf, reason: String },
    #[error("cannot listen on {addr}: {reason}")]
    Listen { addr: String, reason: String },
    #[error("{what}: {reason}")]
    Json { what: &'static str, reason: String },
}
