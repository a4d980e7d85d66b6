//! Proves the whole pipeline (folder loading, thermal/RGB detection, canonical corner order,
//! OpenCV init, joint LM, covariance) recovers a known rig: synthetic board sets rendered
//! through `CameraModel` (Lepton 160×120-like and Boson 640×512-like thermal cores beside a
//! 1280×720-like RGB camera, 40 (Lepton) and 30 (Boson) views with tilts up to ±45°, both thermal polarities) must come
//! back within the accuracy bounds: focal < 0.2 %, principal point < 0.5 px, extrinsic rotation
//! < 0.1°, translation < 1 % of the baseline, and the truth inside the reported 3σ.
//! Does NOT prove accuracy on real optics (blur, non-uniformity): the renderer is an ideal
//! box-filtered chessboard with Gaussian noise; `s3tir-firmware-sim board` output is the
//! lead's integration test.
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use s3tir_calib::solve::pipeline::{PipelineOptions, calibrate_folder};
use s3tir_calib::synth::{self, SynthOptions};

#[test]
fn lepton_beside_720p_is_recovered_with_coated_squares_dark() {
    let dir = tempfile::tempdir().unwrap();
    let rig = synth::rig(synth::lepton(), synth::rgb_720p());
    // 40 views: at 160×120 the extrinsic rotation 1σ is ≈ 0.04° per tilt axis with 30 views,
    // too close to the 0.1° bound for a seed-independent test.
    let opts = SynthOptions::new(synth::default_board(), 40, 11);
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    assert_eq!(
        cal.pairs_used, 40,
        "all 40 pairs should be detected; problems: {:#?}",
        cal.problems
    );
    assert!(
        cal.polarity_note.contains("40 say coated_dark"),
        "auto polarity vote: {}",
        cal.polarity_note
    );
    common::assert_truth("lepton, coated dark", &cal, &rig);
}

#[test]
fn boson_beside_720p_is_recovered_with_inverted_polarity() {
    let dir = tempfile::tempdir().unwrap();
    let rig = synth::rig(synth::boson(), synth::rgb_720p());
    let mut opts = SynthOptions::new(synth::default_board(), 30, 12);
    opts.coated_bright = true;
    opts.thermal_noise = 3.0;
    synth::write_board_folder(dir.path(), &rig, &opts).unwrap();
    let cal = calibrate_folder(dir.path(), &PipelineOptions::default()).unwrap();
    assert_eq!(
        cal.pairs_used, 30,
        "all 30 pairs should be detected; problems: {:#?}",
        cal.problems
    );
    assert!(
        cal.polarity_note.contains("coated_bright by vote")
            && cal.polarity_note.contains("30 coated_bright"),
        "auto polarity should find the coated squares bright in every pair: {}",
        cal.polarity_note
    );
    common::assert_truth("boson, coated bright", &cal, &rig);
}
