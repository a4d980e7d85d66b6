//! The stage's output folder: never overwritten, built in `OUT.partial` (marked as this
//! stage's unfinished work, cleared by the next run) and renamed to `OUT` when complete.

use std::path::{Path, PathBuf};

use super::PosesError;

/// Marks a folder as this stage's unfinished work (safe to remove on the next run).
const PARTIAL_MARKER: &str = ".s3tir-poses-partial";

/// The folder the stage builds in: `OUT.partial`, renamed to `OUT` when everything is written.
fn partial_dir(out: &Path) -> PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    out.with_file_name(name)
}

/// A folder or file of the output that could not be created, written or moved.
fn write_err(path: &Path, e: std::io::Error) -> PosesError {
    PosesError::Write {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

/// Checks that `out` is free (never overwritten), clears a previous run's unfinished
/// `OUT.partial` (identified by its marker) and creates a fresh one.
pub(super) fn start_output(out: &Path) -> Result<PathBuf, PosesError> {
    let err = |path: &Path, reason: String| PosesError::Output {
        path: path.to_path_buf(),
        reason,
    };
    if let Ok(mut it) = std::fs::read_dir(out)
        && it.next().is_some()
    {
        return Err(err(
            out,
            "exists and is not empty: the poses stage never overwrites a dataset (choose another --dataset/--out or remove it)".into(),
        ));
    }
    let partial = partial_dir(out);
    if partial.exists() {
        if !partial.join(PARTIAL_MARKER).is_file() {
            return Err(err(
                &partial,
                "exists and is not an unfinished poses run of this tool: remove it or choose another output".into(),
            ));
        }
        std::fs::remove_dir_all(&partial).map_err(|e| write_err(&partial, e))?;
    }
    std::fs::create_dir_all(&partial).map_err(|e| write_err(&partial, e))?;
    std::fs::write(partial.join(PARTIAL_MARKER), "unfinished s3tir poses run\n")
        .map_err(|e| write_err(&partial, e))?;
    Ok(partial)
}

/// Renames the finished `partial` folder to `out`.
pub(super) fn finish_output(partial: &Path, out: &Path) -> Result<(), PosesError> {
    std::fs::remove_file(partial.join(PARTIAL_MARKER)).map_err(|e| write_err(partial, e))?;
    if out.is_dir() {
        // An empty folder the user made for it.
        std::fs::remove_dir(out).map_err(|e| write_err(out, e))?;
    }
    std::fs::rename(partial, out).map_err(|e| write_err(out, e))
}
