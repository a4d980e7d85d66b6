//! Proves the OpenCV binding is linked and our detector wrapper finds real boards: every left
//! image of OpenCV's stereo sample set (9x6 inner corners) is detected with 54 corners, and a
//! plain OpenCV `calibrateCamera` on those detections lands near OpenCV's reference figures for
//! the set (SB detector: left camera RMS 0.235 px). Does NOT test our own solver (that is the calibration pipeline's).
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use s3tir_calib::detect::chessboard::{self, Detector};

fn data_dir() -> PathBuf {
    let dir = std::env::var_os("S3TIR_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data/opencv-stereo");
    assert!(
        dir.join("left01.jpg").is_file(),
        "{} has no left01.jpg: the shared/ folder must sit beside the clone (or set S3TIR_SHARED_DIR)",
        dir.display()
    );
    dir
}

#[test]
fn finds_all_54_corners_in_left01() {
    let path = data_dir().join("left01.jpg");
    let grey = chessboard::read_grey(&path).unwrap();
    assert_eq!(grey.dimensions(), (640, 480));
    let mat = chessboard::mat_from_luma(&grey).unwrap();
    let det = chessboard::find_chessboard(&mat, 9, 6)
        .unwrap()
        .unwrap_or_else(|| panic!("no 9x6 board found in {}", path.display()));
    assert_eq!(det.corners_px.len(), 54, "want 9x6 = 54 corners");
    assert_eq!(
        det.detector,
        Detector::SectorBased,
        "SB detector should find this board"
    );
    for c in &det.corners_px {
        assert!(
            c.x > 0.0 && c.x < 639.0 && c.y > 0.0 && c.y < 479.0,
            "corner {c} outside the image"
        );
    }
    // Neighbouring corners along a row are one square apart: roughly equal spacing.
    let d01 = (det.corners_px[1] - det.corners_px[0]).length();
    let d12 = (det.corners_px[2] - det.corners_px[1]).length();
    assert!(
        (d01 / d12 - 1.0).abs() < 0.2,
        "row spacing {d01} vs {d12} not a chessboard row"
    );
}

#[test]
fn opencv_calibration_on_our_detections_matches_the_reference() {
    let dir = data_dir();
    let mut object_points = Vector::<Vector<Point3f>>::new();
    let mut image_points = Vector::<Vector<Point2f>>::new();
    let board: Vector<Point3f> = (0..6)
        .flat_map(|r| (0..9).map(move |c| Point3f::new(c as f32 * 25.0, r as f32 * 25.0, 0.0)))
        .collect();
    let names = [
        "01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14",
    ];
    for n in names {
        let path = dir.join(format!("left{n}.jpg"));
        let mat = chessboard::mat_from_luma(&chessboard::read_grey(&path).unwrap()).unwrap();
        let det = chessboard::find_chessboard(&mat, 9, 6)
            .unwrap()
            .unwrap_or_else(|| panic!("board not found in {}", path.display()));
        image_points.push(
            det.corners_px
                .iter()
                .map(|p| Point2f::new(p.x as f32, p.y as f32))
                .collect(),
        );
        object_points.push(board.clone());
    }
    let mut k = Mat::default();
    let mut dist = Mat::default();
    let mut rvecs = Vector::<Mat>::new();
    let mut tvecs = Vector::<Mat>::new();
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        100,
        f64::EPSILON,
    )
    .unwrap();
    let rms = opencv::calib3d::calibrate_camera(
        &object_points,
        &image_points,
        Size::new(640, 480),
        &mut k,
        &mut dist,
        &mut rvecs,
        &mut tvecs,
        0,
        criteria,
    )
    .unwrap();
    let fx = *k.at_2d::<f64>(0, 0).unwrap();
    let cx = *k.at_2d::<f64>(0, 2).unwrap();
    // Reference (OpenCV on the same images): SB detector, left camera RMS 0.235 px; OpenCV's own
    // left_intrinsics.yml: f = 535.9, c = (342.3, 235.6).
    assert!(
        rms < 0.30,
        "RMS {rms:.3} px, want < 0.30 (reference 0.235 px)"
    );
    assert!(
        (fx - 535.9).abs() / 535.9 < 0.02,
        "fx {fx:.1}, want 535.9 within 2 %"
    );
    assert!(
        (cx - 342.3).abs() < 10.0,
        "cx {cx:.1}, want 342.3 within 10 px"
    );
}
