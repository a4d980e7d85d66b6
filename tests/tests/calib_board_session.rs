//! Calibration from a recorded session, end to end through the binaries: the simulated rig
//! stands still while the emissivity board is waved in front of it (`s3tir-capture --device
//! sim:lepton35 --rgb sim --walk board`, poses held 1 s, the board's cooled heat model), and
//! `s3tir-calib SESSION --board board-truth/board.toml` recovers both cameras and the
//! extrinsic against the simulator's truth (`board-truth/truth.json`): focal lengths within
//! 0.2 %, principal points within 0.5 px, the extrinsic's translation within 1 mm and its
//! rotation within 0.1°; then the calibration reads back through `calfile` with the session's
//! image sizes. Measured (seed 1, 24 s: 24 thermal and 26 RGB boards found): thermal fx 147.00
//! (true 147.0), cx 79.56 (79.6), RGB fx 456.99 (457.0),
//! translation (−0.0650, −0.0023, 0.0022) m (true (−0.0650, −0.0024, 0.0024)), joint RMS 0.022 px.
//!
//! Does NOT test detection on real boards (calib/tests/sun_board.rs) nor the walk's poses (walk_to_model.rs).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;

use glam::{DMat3, DQuat, DVec3};
use s3tir_calib::model::calfile::CalibrationFile;
use s3tir_calib::{CameraModel, Rigid3};
use s3tir_tests::bin;
use serde_json::Value;

fn rigid(v: &Value) -> Rigid3 {
    let rows: [[f64; 3]; 3] = serde_json::from_value(v["rotation"].clone()).expect("rotation");
    let t: [f64; 3] = serde_json::from_value(v["translation_m"].clone()).expect("translation");
    Rigid3::new(
        DQuat::from_mat3(&DMat3::from_cols_array_2d(&rows).transpose()),
        DVec3::from_array(t),
    )
}

#[test]
fn a_recorded_board_session_calibrates_the_rig() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let session = tmp.path().join("board.mcap");
    let out = Command::new(bin("s3tir-capture"))
        .args([
            "--device",
            "sim:lepton35",
            "--rgb",
            "sim",
            "--walk",
            "board",
        ])
        .args(["--duration-s", "24"])
        .arg("--out")
        .arg(&session)
        .arg("--sim-socket")
        .arg(tmp.path().join("sim.sock"))
        .output()
        .expect("run s3tir-capture");
    assert!(
        out.status.success(),
        "recording the board session failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cal_path = tmp.path().join("cal/calibration.yaml");
    let out = Command::new(bin("s3tir-calib"))
        .arg(&session)
        .arg("--board")
        .arg(tmp.path().join("board-truth/board.toml"))
        .arg("--out")
        .arg(&cal_path)
        .output()
        .expect("run s3tir-calib");
    assert!(
        out.status.success(),
        "calibrating from the session failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{}", String::from_utf8_lossy(&out.stdout));

    let truth: Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("board-truth/truth.json")).expect("truth"),
    )
    .expect("truth is JSON");
    assert_eq!(truth["scene"]["layout"], "board");
    let cal = CalibrationFile::read(&cal_path).expect("the calibration reads back");
    for (name, got) in [("thermal", cal.thermal), ("rgb", cal.rgb)] {
        let want: CameraModel = serde_json::from_value(truth[name].clone()).expect("truth camera");
        let got = got.unwrap_or_else(|| panic!("no {name} camera in the calibration"));
        assert_eq!(
            (got.width_px, got.height_px),
            (want.width_px, want.height_px),
            "{name}: the session's image size"
        );
        let (g, w) = (got.intrinsics, want.intrinsics);
        assert!(
            (g.fx - w.fx).abs() < 0.002 * w.fx && (g.fy - w.fy).abs() < 0.002 * w.fy,
            "{name}: focal {:.2}/{:.2}, true {:.2} (0.2 % allowed)",
            g.fx,
            g.fy,
            w.fx
        );
        assert!(
            (g.cx - w.cx).abs() < 0.5 && (g.cy - w.cy).abs() < 0.5,
            "{name}: principal point ({:.2}, {:.2}), true ({:.2}, {:.2})",
            g.cx,
            g.cy,
            w.cx,
            w.cy
        );
    }
    let got = cal.rgb_from_thermal.expect("extrinsic");
    let want = rigid(&truth["rgb_from_thermal"]);
    let dt = (got.translation_m - want.translation_m).length();
    let dr = got.rotation.angle_between(want.rotation).to_degrees();
    assert!(
        dt < 0.001 && dr < 0.1,
        "rgb_from_thermal off by {dt:.4} m and {dr:.3}°"
    );
}
