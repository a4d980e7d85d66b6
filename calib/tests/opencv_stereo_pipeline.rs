//! Proves the full pipeline on real images: OpenCV's stereo samples (13 pairs, 640×480,
//! 9×6 inner corners, 25 mm) laid out as a board folder (left → thermal/, right → rgb/, stems
//! `01`…`14`) must give all 13 pairs and per-camera and joint RMS no worse than OpenCV's own
//! SB-detector figures on the same images (left 0.235, right 0.236, stereo 0.257 px)
//! plus a stated margin of 0.01 px. RMS is over inlier corners; the test also bounds the number
//! of corners the 4σ test rejected (≤ 1 %), so the comparison is not won by discarding data.
//! Does NOT prove thermal-specific detection (these are visible-light images).
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::PathBuf;

use s3tir_calib::solve::pipeline::{PipelineOptions, calibrate_folder};

const MARGIN_PX: f64 = 0.01;

fn data_dir() -> PathBuf {
    common::shared_data("opencv-stereo")
}

#[test]
fn opencv_stereo_samples_calibrate_at_least_as_well_as_opencv_sb() {
    let src = data_dir();
    assert!(
        src.join("left01.jpg").is_file(),
        "{} has no left01.jpg",
        src.display()
    );
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("thermal")).unwrap();
    std::fs::create_dir_all(dir.path().join("rgb")).unwrap();
    std::fs::write(
        dir.path().join("board.toml"),
        "[board]\ninner_corners = [9, 6]\nsquare_mm = 25.0\n",
    )
    .unwrap();
    for n in [
        "01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14",
    ] {
        std::fs::copy(
            src.join(format!("left{n}.jpg")),
            dir.path().join(format!("thermal/{n}.jpg")),
        )
        .unwrap();
        std::fs::copy(
            src.join(format!("right{n}.jpg")),
            dir.path().join(format!("rgb/{n}.jpg")),
        )
        .unwrap();
    }
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    let left = cal.cameras[0].as_ref().unwrap();
    let right = cal.cameras[1].as_ref().unwrap();
    eprintln!(
        "left RMS {:.4} (all corners {:.4}, init {:.4}), right RMS {:.4} (all {:.4}, init {:.4}), joint {:.4}, rejected {}, problems {:?}, warnings {:?}",
        left.rms_px,
        left.rms_all_px,
        left.init_rms_px,
        right.rms_px,
        right.rms_all_px,
        right.init_rms_px,
        cal.joint_rms_px,
        cal.rejected.len(),
        cal.problems,
        cal.warnings
    );
    assert_eq!(
        cal.pairs_used, 13,
        "want all 13 pairs; problems: {:?}",
        cal.problems
    );
    assert!(
        left.rms_px <= 0.235 + MARGIN_PX,
        "left RMS {:.4} px, want ≤ 0.235 + {MARGIN_PX}",
        left.rms_px
    );
    assert!(
        right.rms_px <= 0.236 + MARGIN_PX,
        "right RMS {:.4} px, want ≤ 0.236 + {MARGIN_PX}",
        right.rms_px
    );
    assert!(
        cal.joint_rms_px <= 0.257 + MARGIN_PX,
        "joint RMS {:.4} px, want ≤ 0.257 + {MARGIN_PX}",
        cal.joint_rms_px
    );
    let corners = 2 * 13 * 54;
    assert!(
        cal.rejected.len() * 100 <= corners,
        "rejected {} of {corners} corners, want ≤ 1 %",
        cal.rejected.len()
    );
    // Sanity against OpenCV's shipped left intrinsics (f = 535.9).
    let fx = left.model.intrinsics.fx;
    assert!(
        (fx - 535.9).abs() / 535.9 < 0.02,
        "left fx {fx:.1}, want 535.9 within 2 %"
    );
    // The extrinsic: the two cameras sit side by side (|t| ≈ 3.3 board squares in OpenCV's sample).
    let t = cal.rgb_from_thermal.unwrap().translation_m;
    assert!(
        t.x.abs() > t.y.abs() && t.x.abs() > t.z.abs(),
        "baseline {t} should be mostly along x"
    );
}
