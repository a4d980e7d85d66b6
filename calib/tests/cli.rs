//! Proves the `s3tir-calib BOARD_DIR --out … --report … --summary-json …` command line works
//! end to end on OpenCV's stereo samples: exit status 0, the summary JSON carries its
//! keys with finite values, calibration.yaml and every export are written, the report has its
//! markdown, PNG plots and a self-contained `report.html` (the 8 plots embedded and linked, the
//! per-view, rejected-corner, warning and bad-input sections); `.mcap` input without `--board`
//! fails naming the flag; an error is printed once; `bench --real` reports every detector and both solves on real
//! sun-board pairs. Does NOT check the numbers (opencv_stereo_pipeline.rs does).
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::process::Command;

#[test]
fn calibrate_command_writes_summary_exports_and_report() {
    let src = common::shared_data("opencv-stereo");
    let tmp = tempfile::tempdir().unwrap();
    let board = tmp.path().join("board");
    std::fs::create_dir_all(board.join("thermal")).unwrap();
    std::fs::create_dir_all(board.join("rgb")).unwrap();
    std::fs::write(
        board.join("board.toml"),
        "[board]\ninner_corners = [9, 6]\nsquare_mm = 25.0\n",
    )
    .unwrap();
    for n in ["01", "02", "03", "04", "05", "06", "07", "08"] {
        std::fs::copy(
            src.join(format!("left{n}.jpg")),
            board.join(format!("thermal/thermal_{n}.jpg")),
        )
        .unwrap();
        std::fs::copy(
            src.join(format!("right{n}.jpg")),
            board.join(format!("rgb/rgb_{n}.jpg")),
        )
        .unwrap();
    }
    let out = tmp.path().join("out/calibration.yaml");
    let report = tmp.path().join("report");
    let summary = tmp.path().join("summary.json");
    let result = Command::new(env!("CARGO_BIN_EXE_s3tir-calib"))
        .arg(&board)
        .arg("--out")
        .arg(&out)
        .arg("--report")
        .arg(&report)
        .arg("--summary-json")
        .arg(&summary)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "exit {:?}\nstdout {stdout}\nstderr {}",
        result.status,
        String::from_utf8_lossy(&result.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    for camera in ["thermal", "rgb"] {
        for key in [
            "images",
            "views_found",
            "views_used",
            "rms_px",
            "fx",
            "fy",
            "cx",
            "cy",
        ] {
            let v = json[camera][key].as_f64().unwrap_or_else(|| {
                panic!("summary {camera}.{key} missing or not a number: {json}")
            });
            assert!(v.is_finite() && v > 0.0, "{camera}.{key} = {v}");
        }
        assert_eq!(json[camera]["images"], 8, "{camera} images");
        for key in ["mono_rms_px", "mono_rms_all_corners_px"] {
            let v = json[camera][key].as_f64().unwrap_or_else(|| {
                panic!("summary {camera}.{key} missing or not a number: {json}")
            });
            assert!(
                v.is_finite() && v > 0.0 && v < 1.0,
                "{camera}.{key} = {v}: the camera alone on OpenCV's samples is well under 1 px"
            );
        }
        assert!(
            json[camera]["corner_refinement"]["kept"].is_string(),
            "{camera}.corner_refinement.kept names the refinement: {}",
            json[camera]["corner_refinement"]
        );
    }
    assert_eq!(json["pairs_found"], 8, "pairs_found");
    assert_eq!(
        json["pairs_inconsistent"].as_array().map(Vec::len),
        Some(0),
        "OpenCV's stereo samples are rigid pairs: none inconsistent ({})",
        json["pairs_inconsistent"]
    );
    assert_eq!(json["pairs_used"], 8, "pairs_used");
    assert!(
        json["joint_rms_px"].as_f64().unwrap() < 0.5,
        "joint_rms_px {}",
        json["joint_rms_px"]
    );
    let rot = json["rgb_from_thermal"]["rotation"].as_array().unwrap();
    assert_eq!(rot.len(), 3, "rotation rows");
    assert!(
        rot.iter().all(|r| r.as_array().unwrap().len() == 3),
        "3x3 rotation: {rot:?}"
    );
    assert_eq!(
        json["rgb_from_thermal"]["translation"]
            .as_array()
            .unwrap()
            .len(),
        3
    );
    let dir = out.parent().unwrap();
    for name in [
        "calibration.yaml",
        "calibration.opencv-thermal.yaml",
        "calibration.opencv-rgb.yaml",
        "calibration.opencv-stereo.yaml",
        "calibration.ros-thermal.yaml",
        "calibration.ros-rgb.yaml",
        "calibration.camchain.yaml",
        "calibration.colmap-cameras.txt",
    ] {
        let text =
            std::fs::read_to_string(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!text.contains("nan"), "{name} has NaN");
    }
    let yaml = std::fs::read_to_string(&out).unwrap();
    assert!(
        yaml.contains("format: s3tir-calibration/1") && yaml.contains("rgb_from_thermal:"),
        "{yaml}"
    );
    // calibration.yaml reads back through the reader the poses stage and the trainer use, with
    // the models the COLMAP export carries.
    let cal = s3tir_calib::model::calfile::CalibrationFile::read(&out)
        .unwrap_or_else(|e| panic!("calibration.yaml must read back: {e}"));
    let (thermal, rgb) = (cal.thermal.expect("thermal"), cal.rgb.expect("rgb"));
    assert!(cal.rgb_from_thermal.is_some(), "the extrinsic reads back");
    // The OpenCV exports read back through OpenCV's own FileStorage.
    {
        use opencv::core::{FileStorage, FileStorage_Mode, Mat};
        use opencv::prelude::*;
        let path = dir.join("calibration.opencv-thermal.yaml");
        let fs = FileStorage::new(
            path.display().to_string(),
            FileStorage_Mode::READ as i32,
            "",
        )
        .unwrap();
        assert!(
            fs.is_opened().unwrap(),
            "OpenCV cannot open {}",
            path.display()
        );
        let k: Mat = fs.get("camera_matrix").unwrap().mat().unwrap();
        let fx = *k.at_2d::<f64>(0, 0).unwrap();
        let cy = *k.at_2d::<f64>(1, 2).unwrap();
        assert!(
            (fx - thermal.intrinsics.fx).abs() < 1e-6 * fx
                && (cy - thermal.intrinsics.cy).abs() < 1e-6,
            "OpenCV reads fx {fx}, cy {cy}; calibration.yaml has {:?}",
            thermal.intrinsics
        );
        let d: Mat = fs.get("distortion_coefficients").unwrap().mat().unwrap();
        assert_eq!(d.total(), 5, "5 distortion coefficients");
        let path = dir.join("calibration.opencv-stereo.yaml");
        let fs = FileStorage::new(
            path.display().to_string(),
            FileStorage_Mode::READ as i32,
            "",
        )
        .unwrap();
        let t: Mat = fs.get("T").unwrap().mat().unwrap();
        let want = cal.rgb_from_thermal.expect("extrinsic").translation_m;
        assert!(
            (*t.at::<f64>(0).unwrap() - want.x).abs() < 1e-9,
            "OpenCV reads T_x {:?}, calibration.yaml {want:?}",
            t.at::<f64>(0)
        );
    }
    // The COLMAP export reads back through the codec the trainer loads datasets with.
    let cams =
        s3tir_calib::model::colmap::read_cameras_text(&dir.join("calibration.colmap-cameras.txt"))
            .unwrap_or_else(|e| panic!("the COLMAP export must read back: {e}"));
    assert_eq!(cams.len(), 2, "thermal and rgb cameras expected: {cams:?}");
    for c in &cams {
        let want = if c.id == 1 { thermal } else { rgb };
        assert_eq!(
            (c.model.width_px, c.model.height_px),
            (640, 480),
            "camera {} size",
            c.id
        );
        let (a, b) = (c.model.intrinsics, want.intrinsics);
        assert!(
            (a.fx - b.fx).abs() < 1e-6 * b.fx && (a.cx - b.cx).abs() < 1e-6,
            "camera {}: COLMAP export {a:?} and calibration.yaml {b:?} must agree (½-px shift undone)",
            c.id
        );
        assert!((c.model.distortion.k1 - want.distortion.k1).abs() < 1e-8);
    }
    for name in [
        "report.md",
        "per_view_rms_thermal.png",
        "residuals_rgb.png",
        "coverage_thermal.png",
        "coverage_rgb.png",
        "rms_vs_iteration.png",
        "rms_vs_time.png",
        "iterations.csv",
    ] {
        let meta =
            std::fs::metadata(report.join(name)).unwrap_or_else(|e| panic!("report/{name}: {e}"));
        assert!(meta.len() > 100, "report/{name} is {} bytes", meta.len());
    }
    // report.html: self-contained (every plot embedded), linking the PNGs, with the tables.
    let html = std::fs::read_to_string(report.join("report.html"))
        .unwrap_or_else(|e| panic!("report/report.html: {e}"));
    let embedded = html
        .matches("src=\"data:image/png;base64,iVBORw0KGgo")
        .count();
    assert_eq!(
        embedded, 8,
        "report.html should embed 8 PNG plots (3 per camera + 2 RMS curves), found {embedded}"
    );
    for needle in [
        "<!DOCTYPE html>",
        "href=\"per_view_rms_thermal.png\"",
        "href=\"residuals_rgb.png\"",
        "href=\"coverage_thermal.png\"",
        "href=\"rms_vs_iteration.png\"",
        "href=\"rms_vs_time.png\"",
        "id=\"per-view-thermal\"",
        "id=\"per-view-rgb\"",
        "id=\"rejected\"",
        "id=\"warnings\"",
        "id=\"bad-input\"",
        "rgb_from_thermal",
        "</html>",
    ] {
        assert!(
            html.contains(needle),
            "report.html lacks {needle:?} ({} bytes)",
            html.len()
        );
    }
}

#[test]
fn mcap_input_without_board_is_refused_with_a_clear_error() {
    let result = Command::new(env!("CARGO_BIN_EXE_s3tir-calib"))
        .arg("/nonexistent/session.mcap")
        .output()
        .unwrap();
    assert!(!result.status.success(), "must fail");
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.contains("pass --board board.toml"),
        "stderr should name --board: {stderr}"
    );
}

/// An error is printed once: `poses` given a session that does not exist says so in one
/// `error: …` line, each level of the cause chain once — the OS cause ("No such file or
/// directory") once in all of stderr, the session's path at most once on any line — with no
/// `Caused by:` list repeating the causes under it. (A folder is an input of its own now: a
/// folder of images.)
#[test]
fn an_error_is_printed_once() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("missing.mcap");
    let result = Command::new(env!("CARGO_BIN_EXE_s3tir-calib"))
        .arg("poses")
        .arg(&dir)
        .arg("--out")
        .arg(tmp.path().join("dataset"))
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    assert!(
        !result.status.success(),
        "a session that does not exist: must fail"
    );
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.lines().any(|l| l.starts_with("error: ")),
        "expected one `error: …` line in stderr: {stderr}"
    );
    assert_eq!(
        stderr.matches("No such file or directory").count(),
        1,
        "expected the OS cause \"No such file or directory\" exactly once in stderr: {stderr}"
    );
    let path = dir.display().to_string();
    for line in stderr.lines() {
        assert!(
            line.matches(path.as_str()).count() <= 1,
            "expected the session's path at most once per line, {line:?} repeats it; stderr: {stderr}"
        );
    }
    assert!(
        stderr.contains(&path),
        "expected the error to name the session {path}: {stderr}"
    );
    assert!(
        !stderr.contains("Caused by"),
        "expected no `Caused by:` list repeating the causes: {stderr}"
    );
}

/// `s3tir-calib bench --real DIR` on six real sun-board pairs: every detector's row for both
/// cameras with its boards found (OpenCV's SB finds all six thermal boards on plain grey, and
/// so must s3tir), s3tir's parallel detection, and both solves on the same corners. Timings
/// are printed, never asserted.
#[test]
fn bench_real_reports_each_detector_and_both_solves_on_sun_board() {
    let src = common::shared_data("sun-board");
    let tmp = tempfile::tempdir().unwrap();
    let board = tmp.path().join("board");
    for camera in ["thermal", "rgb"] {
        std::fs::create_dir_all(board.join(camera)).unwrap();
        for n in ["05", "06", "08", "11", "12", "13"] {
            std::fs::copy(
                src.join(format!("{camera}/Img{n}.jpg")),
                board.join(format!("{camera}/Img{n}.jpg")),
            )
            .unwrap();
        }
    }
    std::fs::write(
        board.join("board.toml"),
        "[board]\ninner_corners = [6, 5]\nsquare_mm = 100.0\n",
    )
    .unwrap();
    let result = Command::new(env!("CARGO_BIN_EXE_s3tir-calib"))
        .args(["bench", "--real"])
        .arg(&board)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        result.status.success(),
        "bench --real failed:\n{stdout}\n{stderr}"
    );
    let row = |needle: &str, nth: usize| -> String {
        stdout
            .lines()
            .filter(|l| l.contains(needle))
            .nth(nth)
            .unwrap_or_else(|| panic!("no row #{nth} with {needle:?} in:\n{stdout}"))
            .to_string()
    };
    assert!(
        row("thermal 640x480 s3tir", 0).contains("6/6"),
        "s3tir must find all 6 thermal boards:\n{stdout}"
    );
    assert!(
        row("rgb 1014x760 s3tir", 0).contains("6/6"),
        "s3tir must find all 6 RGB boards:\n{stdout}"
    );
    // Thermal rows come first: OpenCV's SB on plain grey finds every thermal board.
    assert!(
        row("OpenCV SB (EXHAUSTIVE | ACCURACY)", 0).contains("6/6"),
        "OpenCV SB finds all 6 thermal boards here:\n{stdout}"
    );
    assert_eq!(
        stdout.matches("OpenCV classic + cornerSubPix").count(),
        2,
        "one classic-detector row per camera:\n{stdout}"
    );
    assert!(
        stdout.contains("solve on s3tir's detections (6 pairs")
            && stdout.contains("OpenCV (calibrateCamera x2 + stereoCalibrate"),
        "both solves must be reported on the six pairs:\n{stdout}"
    );
}
