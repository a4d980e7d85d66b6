//! The viewer's files: the page and its script (ours, inside the binary) and the vendored
//! renderer (three.js, MIT; `scripts/install-viewer.py` writes it from the npm registry's
//! tarball into `DATA/viewer/three-VERSION/`, and each file is checked against the SHA-256
//! below — the same values as in the script — before it is served).

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use super::ViewError;
use crate::installed::data_home;

/// The page: the controls, the colour bar and the readout around the 3-D canvas.
pub const INDEX_HTML: &str = include_str!("page/index.html");
/// The page's script: the scene, palettes, colour bar, picking.
pub const VIEWER_JS: &str = include_str!("page/viewer.js");

/// three.js's version, as installed by `scripts/install-viewer.py`.
pub const THREE_VERSION: &str = "0.187.0";
/// Environment variable naming the folder of the vendored files instead of the data folder's.
pub const ASSETS_ENV: &str = "S3TIR_VIEWER_ASSETS";
/// The vendored files (served under `/vendor/`) and their SHA-256.
pub const VENDORED: [(&str, &str); 5] = [
    (
        "three.module.js",
        "104f56145899722094556490d787aae0617cc2fc3382f31df02d724ea1aee341",
    ),
    (
        "three.core.js",
        "613e370f76638fdef83926642bf256dc9615684922de1ce1f63a8583e5d78578",
    ),
    (
        "OrbitControls.js",
        "e7fca2fe9e7670a828af9b28084669a5909445b7f36f1f26cee9bf8f2961c32c",
    ),
    (
        "PLYLoader.js",
        "751ff866f793ba1fc9181425748d88b7f9234c6e9983386fdaf2e664221340f2",
    ),
    (
        "LICENSE",
        "8b378ebe60e2fe500158cb0ac71cb5e8b7d92953c2abcc63a0eb90499653b5bc",
    ),
];

/// Where the vendored files are looked for: `$S3TIR_VIEWER_ASSETS`, else
/// `DATA/viewer/three-VERSION/`.
pub fn default_dir() -> Option<PathBuf> {
    std::env::var_os(ASSETS_ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| data_home().map(|d| d.join("viewer").join(format!("three-{THREE_VERSION}"))))
}

/// The vendored files, read and checked once when the viewer starts.
#[derive(Debug, Clone)]
pub struct Vendored {
    files: Vec<(&'static str, Vec<u8>)>,
}

impl Vendored {
    /// Reads every file of [`VENDORED`] from `dir` and checks its SHA-256.
    pub fn load(dir: &Path) -> Result<Self, ViewError> {
        let bad = |reason: String| ViewError::Assets {
            dir: dir.to_path_buf(),
            version: THREE_VERSION,
            reason,
        };
        let mut files = Vec::with_capacity(VENDORED.len());
        for (name, expected) in VENDORED {
            let path = dir.join(name);
            let bytes = std::fs::read(&path).map_err(|e| bad(format!("{name}: {e}")))?;
            let found = format!("{:x}", Sha256::digest(&bytes));
            if found != expected {
                return Err(bad(format!(
                    "{name} has SHA-256 {found}, expected {expected}"
                )));
            }
            files.push((name, bytes));
        }
        Ok(Self { files })
    }

    /// The file called `name` (one of [`VENDORED`]), if it is one.
    pub fn get(&self, name: &str) -> Option<&[u8]> {
        self.files
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, b)| b.as_slice())
    }
}
