//! Support for the end-to-end tests in `tests/tests/`: locating the workspace's binaries,
//! reading the JSON the binaries print, and reading a simulated walk's truth
//! ([`read_walk_truth`]).
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

/// A real data set of `../shared/data` (the workspace's sibling), or of `$S3TIR_SHARED_DIR/data`.
pub fn shared_data(set: &str) -> PathBuf {
    std::env::var_os("S3TIR_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data")
        .join(set)
}

/// Runs `cmd` (described as `what` in failures) and returns its stdout; panics with both
/// outputs when it cannot start or exits with failure.
pub fn run_ok(cmd: &mut Command, what: &str) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
    assert!(
        out.status.success(),
        "{what} failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The thermal sequence number in a dataset image name the poses stage wrote
/// (`thermal_SEQUENCE.png`); panics on any other name.
pub fn thermal_sequence(name: &str) -> u32 {
    use s3tir_calib::poses::frames::Stream;
    match Stream::parse_file_name(name) {
        Some((Stream::Thermal, seq)) => seq,
        _ => panic!("{name} is not a thermal image name of the poses stage"),
    }
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

/// A rigid transform from the simulator's JSON (`rotation` rows, `translation_m`).
pub fn rigid_from_json(v: &Value) -> s3tir_calib::Rigid3 {
    use glam::{DMat3, DQuat, DVec3};
    let rows: Vec<Vec<f64>> = serde_json::from_value(v["rotation"].clone())
        .unwrap_or_else(|e| panic!("rotation rows: {e}"));
    let m = DMat3::from_cols_array_2d(&[
        [rows[0][0], rows[0][1], rows[0][2]],
        [rows[1][0], rows[1][1], rows[1][2]],
        [rows[2][0], rows[2][1], rows[2][2]],
    ])
    .transpose();
    let t: [f64; 3] = serde_json::from_value(v["translation_m"].clone())
        .unwrap_or_else(|e| panic!("translation_m: {e}"));
    s3tir_calib::Rigid3::new(DQuat::from_mat3(&m), DVec3::from_array(t))
}

/// What a simulated walk's `truth.json` (`s3tir-walk-truth/1`) says.
#[derive(Debug, Clone)]
pub struct WalkTruth {
    /// The rig's true calibration.
    pub cal: s3tir_calib::model::calfile::CalibrationFile,
    /// Diameter of the scene's bounding sphere, metres.
    pub extent_m: f64,
    /// Thermal frames: sequence → world_from_cam.
    pub thermal: std::collections::BTreeMap<u32, s3tir_calib::Rigid3>,
    /// `world_from_board` of the board standing in the room (a walk with `--walk-board`).
    pub board: Option<s3tir_calib::Rigid3>,
}

/// Reads a walk's `truth.json`; panics naming the file when it does not read.
pub fn read_walk_truth(path: &Path) -> WalkTruth {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Value =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let model = |k: &str| -> s3tir_calib::CameraModel {
        serde_json::from_value(v[k].clone()).unwrap_or_else(|e| panic!("truth {k}: {e}"))
    };
    let mut thermal = std::collections::BTreeMap::new();
    for f in v["frames"]
        .as_array()
        .unwrap_or_else(|| panic!("truth has no frames"))
    {
        if f["stream"] == "thermal" {
            let seq = f["sequence"]
                .as_u64()
                .unwrap_or_else(|| panic!("frame sequence"));
            thermal.insert(seq as u32, rigid_from_json(&f["world_from_cam"]));
        }
    }
    // A walk recorded without RGB has `"rgb": null`: a thermal-only calibration.
    let has_rgb = !v["rgb"].is_null();
    WalkTruth {
        cal: s3tir_calib::model::calfile::CalibrationFile {
            thermal: Some(model("thermal")),
            rgb: has_rgb.then(|| model("rgb")),
            rgb_from_thermal: has_rgb.then(|| rigid_from_json(&v["rgb_from_thermal"])),
        },
        extent_m: v["scene"]["extent_m"]
            .as_f64()
            .unwrap_or_else(|| panic!("truth has no scene extent")),
        thermal,
        board: (!v["board"].is_null()).then(|| rigid_from_json(&v["board"])),
    }
}
