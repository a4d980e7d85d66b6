//! Proves the pipeline survives the awkward inputs the brief lists, with a warning or a named
//! per-file problem instead of NaN or an abort: fronto-parallel-only views, a camera that sees
//! the board in only 3 views, boards partly out of frame, pseudo-colour thermal images, bad
//! files (unreadable, wrong size, not an image), a missing camera, nothing usable, and `.mcap`
//! input without `--board` (a clear error; session input itself is tested in
//! `tests/tests/calib_session.rs`). Accuracy here is checked only loosely (these are
//! degraded sets); `synthetic_truth.rs` holds the tight bounds.
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use s3tir_calib::CalibError;
use s3tir_calib::detect::scalar::{Palette, SourceKind};
use s3tir_calib::progress::NoProgress;
use s3tir_calib::solve::pipeline::{Calibration, PipelineOptions, calibrate_folder, detect_folder};
use s3tir_calib::synth::{self, SynthOptions, ThermalFormat};

fn small_rig() -> synth::SynthRig {
    synth::rig(synth::lepton(), synth::rgb_360p())
}

fn finite_everywhere(cal: &Calibration) {
    for c in cal.cameras.iter().flatten() {
        c.model
            .validate()
            .unwrap_or_else(|e| panic!("{} model not finite: {e}", c.camera.name()));
        assert!(c.rms_px.is_finite(), "{} RMS {}", c.camera.name(), c.rms_px);
        let s = c.sigma;
        for v in [s.fx, s.fy, s.cx, s.cy, s.k1, s.k2, s.p1, s.p2, s.k3] {
            assert!(v.is_finite(), "{} σ not finite: {s:?}", c.camera.name());
        }
    }
    if let Some(t) = cal.rgb_from_thermal {
        assert!(
            t.rotation.is_finite() && t.translation_m.is_finite(),
            "extrinsic not finite: {t:?}"
        );
    }
    let yaml = s3tir_calib::report::export::calibration_yaml(cal);
    assert!(!yaml.contains("nan"), "calibration.yaml has NaN:\n{yaml}");
}

#[test]
fn fronto_parallel_only_views_warn_and_stay_finite() {
    let dir = tempfile::tempdir().unwrap();
    let rig = small_rig();
    let mut opts = SynthOptions::new(synth::default_board(), 12, 21);
    opts.max_tilt_deg = 2.0;
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    finite_everywhere(&cal);
    for camera in ["thermal", "rgb"] {
        assert!(
            cal.warnings
                .iter()
                .any(|w| w.starts_with(camera) && w.contains("fronto-parallel")),
            "want a fronto-parallel warning for {camera}; warnings: {:#?}",
            cal.warnings
        );
    }
}

#[test]
fn a_camera_seeing_the_board_in_only_3_views_still_calibrates_with_warnings() {
    let dir = tempfile::tempdir().unwrap();
    let rig = small_rig();
    let mut opts = SynthOptions::new(synth::default_board(), 16, 22);
    opts.rgb_board_views = Some(3);
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    finite_everywhere(&cal);
    let rgb = cal.cameras[1]
        .as_ref()
        .expect("rgb calibrated from 3 views");
    assert_eq!(
        (rgb.images, rgb.views_found, rgb.views_used),
        (16, 3, 3),
        "rgb images/found/used"
    );
    assert_eq!(cal.pairs_used, 3, "3 pairs");
    let empty_rgb = cal
        .problems
        .iter()
        .filter(|p| p.path.to_string_lossy().contains("rgb_") && p.reason.contains("no 9x6 board"))
        .count();
    assert_eq!(
        empty_rgb, 13,
        "each empty RGB image named with its reason: {:#?}",
        cal.problems
    );
    assert!(
        cal.warnings
            .iter()
            .any(|w| w.contains("rgb: the board was found in only 3 views")),
        "warnings: {:#?}",
        cal.warnings
    );
    assert!(
        cal.warnings
            .iter()
            .any(|w| w.contains("only 3 consistent pairs")),
        "warnings: {:#?}",
        cal.warnings
    );
    // The well-observed thermal camera is unaffected.
    let t = cal.cameras[0].as_ref().unwrap().model.intrinsics;
    assert!(
        (t.fx - rig.thermal.intrinsics.fx).abs() / rig.thermal.intrinsics.fx < 0.005,
        "thermal fx {}",
        t.fx
    );
    // Three views still pin the RGB focal length to within a few percent.
    let fx = rgb.model.intrinsics.fx;
    assert!(
        (fx - rig.rgb.intrinsics.fx).abs() / rig.rgb.intrinsics.fx < 0.03,
        "rgb fx {fx}, truth {}",
        rig.rgb.intrinsics.fx
    );
}

#[test]
fn boards_partly_out_of_frame_are_reported_and_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let rig = small_rig();
    let mut opts = SynthOptions::new(synth::default_board(), 14, 23);
    opts.thermal_partly_out = 3;
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    finite_everywhere(&cal);
    let thermal_missing: Vec<_> = cal
        .problems
        .iter()
        .filter(|p| p.path.to_string_lossy().contains("thermal_"))
        .collect();
    assert_eq!(
        thermal_missing.len(),
        3,
        "the 3 partly visible thermal boards are reported: {:#?}",
        cal.problems
    );
    for name in ["thermal_0011.png", "thermal_0012.png", "thermal_0013.png"] {
        assert!(
            thermal_missing
                .iter()
                .any(|p| p.path.ends_with(format!("thermal/{name}"))),
            "{name} missing from {thermal_missing:#?}"
        );
    }
    assert_eq!(cal.pairs_used, 11, "11 complete pairs");
    assert_eq!(
        cal.cameras[1].as_ref().unwrap().views_used,
        14,
        "RGB keeps all 14 views (3 unpaired)"
    );
}

#[test]
fn pseudo_colour_thermal_images_are_inverted_through_the_palette() {
    let dir = tempfile::tempdir().unwrap();
    let rig = small_rig();
    let mut opts = SynthOptions::new(synth::default_board(), 14, 24);
    opts.thermal_format = ThermalFormat::PseudoColour(Palette::Ironbow);
    opts.coated_bright = true;
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let set = detect_folder(dir.path(), &NoProgress).unwrap();
    assert!(
        set.source_kinds.iter().any(|(c, k)| c.name() == "thermal" && *k == SourceKind::PseudoColour(Palette::Ironbow)),
        "thermal images should be recognised as ironbow: {:?}",
        set.source_kinds
    );
    let cal = s3tir_calib::solve::pipeline::calibrate_detections(&set, &PipelineOptions::default())
        .unwrap();
    finite_everywhere(&cal);
    assert_eq!(
        cal.pairs_used, 14,
        "all pairs; problems {:#?}",
        cal.problems
    );
    let fx = cal.cameras[0].as_ref().unwrap().model.intrinsics.fx;
    assert!(
        (fx - rig.thermal.intrinsics.fx).abs() / rig.thermal.intrinsics.fx < 0.005,
        "thermal fx {fx}, truth {}",
        rig.thermal.intrinsics.fx
    );
    let t = cal.rgb_from_thermal.unwrap();
    let err_m = (t.translation_m - rig.rgb_from_thermal.translation_m).length();
    assert!(
        err_m < 0.002,
        "extrinsic translation off by {err_m} m: ordering must agree between palette thermal and RGB"
    );
}

#[test]
fn bad_files_are_named_and_the_run_continues() {
    let dir = tempfile::tempdir().unwrap();
    let rig = small_rig();
    let mut opts = SynthOptions::new(synth::default_board(), 8, 25);
    opts.write_rgb = false;
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let t = dir.path().join("thermal");
    std::fs::write(t.join("thermal_0100.png"), b"not a png").unwrap();
    std::fs::write(t.join("notes.txt"), b"hello").unwrap();
    image::GrayImage::new(80, 60)
        .save(t.join("thermal_0101.png"))
        .unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    let reason = |name: &str| {
        cal.problems
            .iter()
            .find(|p| p.path.ends_with(format!("thermal/{name}")))
            .map(|p| p.reason.clone())
            .unwrap_or_else(|| panic!("{name} not reported: {:#?}", cal.problems))
    };
    assert!(
        reason("thermal_0100.png").contains("unreadable"),
        "{}",
        reason("thermal_0100.png")
    );
    assert!(
        reason("notes.txt").contains("not an image"),
        "{}",
        reason("notes.txt")
    );
    assert!(
        reason("thermal_0101.png").contains("wrong size 80x60"),
        "{}",
        reason("thermal_0101.png")
    );
    assert!(
        cal.cameras[1].is_none() && cal.rgb_from_thermal.is_none(),
        "no RGB folder: thermal alone"
    );
    assert!(
        cal.warnings.iter().any(|w| w.contains("no rgb/ images")),
        "warnings: {:#?}",
        cal.warnings
    );
    assert_eq!(
        cal.cameras[0].as_ref().unwrap().views_used,
        8,
        "problems: {:#?}",
        cal.problems
    );
}

#[test]
fn nothing_usable_fails_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("thermal")).unwrap();
    std::fs::write(
        dir.path().join("board.toml"),
        "[board]\ninner_corners = [9, 6]\nsquare_mm = 30\n",
    )
    .unwrap();
    std::fs::write(dir.path().join("thermal/0001.png"), b"garbage").unwrap();
    let err = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap_err();
    assert!(matches!(err, CalibError::NothingUsable { .. }), "got {err}");
    let msg = err.to_string();
    assert!(
        msg.contains("nothing usable") && msg.contains("0001.png"),
        "message should name the cause: {msg}"
    );
}

#[test]
fn mcap_sessions_without_a_board_are_refused_clearly() {
    let err = calibrate_folder(
        std::path::Path::new("/tmp/session.mcap"),
        &PipelineOptions::default(),
    )
    .unwrap_err();
    assert!(
        matches!(err, CalibError::SessionNeedsBoard { .. }),
        "got {err}"
    );
    assert!(err.to_string().contains("--board board.toml"), "{err}");
}

#[test]
fn square_boards_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("board.toml"),
        "[board]\ninner_corners = [7, 7]\nsquare_mm = 30\n",
    )
    .unwrap();
    let err = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap_err();
    assert!(err.to_string().contains("square boards"), "{err}");
}
