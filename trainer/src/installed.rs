//! What `scripts/install-deps.sh` installs for the trainer outside the binary, and where: the
//! data folder (the LPIPS weights under `lpips/`, the viewer's renderer under `viewer/`).
//! Nothing is downloaded at run time.

use std::path::PathBuf;

/// s3tir's data folder: `$S3TIR_DATA_HOME`, else `$XDG_DATA_HOME/s3tir`, else
/// `~/.local/share/s3tir` (`None` without any of them set). The install scripts use the same
/// rule (`scripts/install-lpips.py`, `scripts/install-viewer.py`).
pub fn data_home() -> Option<PathBuf> {
    let var = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    var("S3TIR_DATA_HOME")
        .or_else(|| var("XDG_DATA_HOME").map(|d| d.join("s3tir")))
        .or_else(|| var("HOME").map(|h| h.join(".local/share/s3tir")))
}
