//! Support for the end-to-end tests in `tests/tests/`: locating the workspace's binaries.
//!
//! `cargo test --workspace` (what `make test` runs) builds every member's binaries into the
//! same profile directory as the test executables; the tests run them from there.

use std::path::PathBuf;

/// Path of a workspace binary built beside the running test executable.
///
/// Panics with instructions when it is missing (the test was run with `-p s3tir-tests` only).
pub fn bin(name: &str) -> PathBuf {
    let exe =
        std::env::current_exe().unwrap_or_else(|e| panic!("cannot locate test executable: {e}"));
    // target/<profile>/deps/<test-exe> -> target/<profile>/<name>
    let profile_dir = exe
        .parent()
        .and_then(|deps| deps.parent())
        .unwrap_or_else(|| panic!("unexpected test executable path {}", exe.display()));
    let path = profile_dir.join(name);
    assert!(
        path.is_file(),
        "{} not built: run the suite with `make test` (cargo test --workspace) so every binary is built",
        path.display()
    );
    path
}
