//! The real sun-board set (`sun-board/` in the shared data folder, `$S3TIR_SHARED_DIR/data`: 47 thermal + RGB pairs of a sun-heated
//! checkerboard from a hand-held DJI dual camera, thermal polarity inverted, 6×5 inner corners,
//! 100 mm squares) through the whole pipeline, with thresholds from OpenCV on the same images
//! (`findChessboardCornersSB` on plain grey + `calibrateCamera`: 47/47 thermal boards, thermal
//! RMS 0.456 px over every corner, fx 656.9):
//! - every thermal and RGB board is found (36/47 thermal while the SB detector ran with
//!   OpenCV's histogram normalisation);
//! - the thermal camera calibrated alone reaches OpenCV's RMS over every corner (≤ 0.46 px),
//!   and its focal length agrees with OpenCV's within 1 %;
//! - the pairs that are not one rigid instant are identified. This set's two cameras did not
//!   expose together: OpenCV's own `stereoCalibrate` with fixed intrinsics leaves 4.7 px RMS,
//!   and pairs such as Img16 and Img31 show the board at visibly different in-plane angles in
//!   the two images. Those two must be flagged, and the pairs kept must be consistent: joint
//!   thermal RMS close to the thermal camera alone (5.16 px joint RMS before the pair
//!   consistency tests);
//! - the extrinsic comes from the consistent pairs with a finite, stated uncertainty.
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::PathBuf;

use s3tir_calib::solve::pairs::PairTest;
use s3tir_calib::solve::pipeline::{PipelineOptions, calibrate_folder};

fn data_dir() -> PathBuf {
    common::shared_data("sun-board")
}

#[test]
fn sun_board_finds_every_board_matches_opencv_mono_and_flags_inconsistent_pairs() {
    let src = data_dir();
    assert!(
        src.join("thermal/Img05.jpg").is_file(),
        "{} has no thermal/Img05.jpg",
        src.display()
    );
    let dir = tempfile::tempdir().unwrap();
    for camera in ["thermal", "rgb"] {
        std::fs::create_dir_all(dir.path().join(camera)).unwrap();
        for entry in std::fs::read_dir(src.join(camera)).unwrap() {
            let path = entry.unwrap().path();
            std::fs::copy(
                &path,
                dir.path().join(camera).join(path.file_name().unwrap()),
            )
            .unwrap();
        }
    }
    std::fs::write(
        dir.path().join("board.toml"),
        "[board]\ninner_corners = [6, 5]\nsquare_mm = 100.0\n",
    )
    .unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    let thermal = cal.cameras[0].as_ref().unwrap();
    let rgb = cal.cameras[1].as_ref().unwrap();
    eprintln!(
        "thermal {}/{} mono RMS {:.4} (all corners {:.4}) joint {:.4} fx {:.2} refinement {:?}; rgb {}/{} mono {:.4} joint {:.4}; pairs found {} used {} inconsistent {}; joint RMS {:.4}; problems {:?}",
        thermal.views_found,
        thermal.images,
        thermal.mono_rms_px,
        thermal.mono_rms_all_px,
        thermal.rms_px,
        thermal.model.intrinsics.fx,
        thermal.refinement,
        rgb.views_found,
        rgb.images,
        rgb.mono_rms_px,
        rgb.rms_px,
        cal.pairs_found,
        cal.pairs_used,
        cal.pairs_inconsistent.len(),
        cal.joint_rms_px,
        cal.problems
    );
    assert_eq!(
        (thermal.images, thermal.views_found),
        (47, 47),
        "every thermal board must be found (OpenCV SB finds 47/47); problems: {:?}",
        cal.problems
    );
    assert_eq!(
        (rgb.images, rgb.views_found),
        (47, 47),
        "every RGB board must be found; problems: {:?}",
        cal.problems
    );
    assert!(
        thermal.mono_rms_all_px <= 0.46,
        "thermal alone: RMS over every corner {:.4} px, want ≤ 0.46 (OpenCV SB + calibrateCamera: 0.456)",
        thermal.mono_rms_all_px
    );
    let fx = thermal.model.intrinsics.fx;
    assert!(
        (fx - 656.9).abs() / 656.9 < 0.01,
        "thermal fx {fx:.2}, want OpenCV's 656.9 within 1 %"
    );
    assert_eq!(
        cal.pairs_found, 47,
        "47 pairs have the board in both images"
    );
    let flagged: Vec<&str> = cal
        .pairs_inconsistent
        .iter()
        .map(|p| p.key.as_str())
        .collect();
    for key in ["Img16", "Img31"] {
        assert!(
            flagged.contains(&key),
            "{key} shows the board at different angles in its two images and must be flagged; flagged: {flagged:?}"
        );
    }
    for p in &cal.pairs_inconsistent {
        let over = match p.test {
            PairTest::Transfer => p.transfer_rms_px,
            PairTest::Residual => p.joint_rms_px[0].max(p.joint_rms_px[1]),
        };
        assert!(
            over > 3.0 * p.mono_rms_px[0].min(p.mono_rms_px[1]),
            "{} was flagged with {over:.2} px against mono {:?}: the figures must show why",
            p.key,
            p.mono_rms_px
        );
    }
    assert!(
        cal.pairs_used >= 3 && cal.pairs_used + cal.pairs_inconsistent.len() == 47,
        "the extrinsic needs ≥ 3 consistent pairs, and every pair is either used or listed (used {}, listed {})",
        cal.pairs_used,
        cal.pairs_inconsistent.len()
    );
    assert!(
        thermal.rms_px < 1.5 * thermal.mono_rms_px,
        "with only consistent pairs the joint thermal RMS {:.3} px must stay near the camera alone ({:.3} px); before pair checks it was 7.86 px",
        thermal.rms_px,
        thermal.mono_rms_px
    );
    let ext = cal
        .rgb_from_thermal
        .expect("an extrinsic from the consistent pairs");
    let sigma = cal.extrinsic_sigma.expect("the extrinsic's uncertainty");
    let ts = sigma.translation_m;
    let rs = sigma.rotation_deg;
    assert!(
        ts.iter().chain(&rs).all(|s| s.is_finite() && *s > 0.0)
            && ts.iter().all(|s| *s < 0.01)
            && rs.iter().all(|s| *s < 0.5),
        "extrinsic σ rotation {rs:?}° translation {ts:?} m must be finite and under 0.5° / 10 mm"
    );
    // The two lenses of a dual camera sit a few centimetres apart.
    assert!(
        ext.translation_m.length() < 0.1,
        "baseline {:.3} m, want a few centimetres",
        ext.translation_m.length()
    );
}
