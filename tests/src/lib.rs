//! Support for the end-to-end tests in `tests/tests/`: locating the workspace's binaries and
//! reading the JSON the binaries print.
//!
//! `cargo test --workspace` (what `make test` runs) builds every member's binaries into the
//! same profile directory as the test executables; the tests run them from there.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

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

/// `s3tir-capture info --json PATH`, parsed; panics with the tool's stderr when it fails.
pub fn capture_info_json(path: &Path) -> Value {
    let out = Command::new(bin("s3tir-capture"))
        .args(["info", "--json"])
        .arg(path)
        .output()
        .unwrap_or_else(|e| panic!("cannot run s3tir-capture info: {e}"));
    assert!(
        out.status.success(),
        "info failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("info --json printed no JSON object: {e}"))
}

/// `s3tir-capture replay --json SESSION [--out OUT]`, parsed; panics with the tool's stderr
/// when it fails.
pub fn capture_replay_json(session: &Path, out: Option<&Path>) -> Value {
    let mut cmd = Command::new(bin("s3tir-capture"));
    cmd.args(["replay", "--json"]).arg(session);
    if let Some(out) = out {
        cmd.arg("--out").arg(out);
    }
    let r = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run s3tir-capture replay: {e}"));
    assert!(
        r.status.success(),
        "replay failed: {}",
        String::from_utf8_lossy(&r.stderr)
    );
    serde_json::from_slice(&r.stdout)
        .unwrap_or_else(|e| panic!("replay --json printed no JSON object: {e}"))
}

fn field<'a>(v: &'a Value, path: &[&str]) -> &'a Value {
    path.iter().fold(v, |x, k| &x[*k])
}

/// The integer at `path` (object keys) in `v`; panics naming the path when it is not one.
pub fn json_u64(v: &Value, path: &[&str]) -> u64 {
    field(v, path)
        .as_u64()
        .unwrap_or_else(|| panic!("{path:?} missing or not an integer in {v}"))
}

/// The number at `path` (object keys) in `v`; panics naming the path when it is not one.
pub fn json_f64(v: &Value, path: &[&str]) -> f64 {
    field(v, path)
        .as_f64()
        .unwrap_or_else(|| panic!("{path:?} missing or not a number in {v}"))
}
