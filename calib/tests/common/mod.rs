//! Shared helpers for calib's integration tests: truth comparison of a calibration against a
//! synthetic set's known rig.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use s3tir_calib::detect::board::Camera;
use s3tir_calib::solve::pipeline::Calibration;
use s3tir_calib::synth::SynthRig;

/// Errors of a calibration against the truth.
#[derive(Debug)]
pub struct TruthErrors {
    /// Relative focal errors (fx, fy) per camera.
    pub focal_rel: [[f64; 2]; 2],
    /// Principal-point errors (px) per camera.
    pub pp_px: [[f64; 2]; 2],
    /// |error| / σ for fx, fy, cx, cy per camera.
    pub intr_sigmas: [[f64; 4]; 2],
    pub rot_deg: f64,
    /// Translation error over baseline.
    pub trans_rel: f64,
    /// |error| / σ per axis of the extrinsic translation and rotation increments.
    pub ext_sigmas: [f64; 6],
}

pub fn compare(cal: &Calibration, truth: &SynthRig) -> TruthErrors {
    let mut focal_rel = [[0.0; 2]; 2];
    let mut pp_px = [[0.0; 2]; 2];
    let mut intr_sigmas = [[0.0; 4]; 2];
    for camera in Camera::BOTH {
        let k = camera.index();
        let r = cal.cameras[k]
            .as_ref()
            .unwrap_or_else(|| panic!("{} not calibrated", camera.name()));
        let t = if k == 0 { truth.thermal } else { truth.rgb };
        let (e, g, s) = (r.model.intrinsics, t.intrinsics, r.sigma);
        focal_rel[k] = [(e.fx - g.fx).abs() / g.fx, (e.fy - g.fy).abs() / g.fy];
        pp_px[k] = [(e.cx - g.cx).abs(), (e.cy - g.cy).abs()];
        intr_sigmas[k] = [
            (e.fx - g.fx).abs() / s.fx,
            (e.fy - g.fy).abs() / s.fy,
            (e.cx - g.cx).abs() / s.cx,
            (e.cy - g.cy).abs() / s.cy,
        ];
    }
    let est = cal.rgb_from_thermal.expect("extrinsic solved");
    let tr = truth.rgb_from_thermal;
    // Rotation error as a left increment: est = exp(w) * truth.
    let w = (est.rotation * tr.rotation.conjugate()).to_scaled_axis();
    let rot_deg = w.length().to_degrees();
    let dt = est.translation_m - tr.translation_m;
    let trans_rel = dt.length() / tr.translation_m.length();
    let s = cal.extrinsic_sigma.expect("extrinsic sigma");
    let ext_sigmas = [
        w.x.to_degrees().abs() / s.rotation_deg[0],
        w.y.to_degrees().abs() / s.rotation_deg[1],
        w.z.to_degrees().abs() / s.rotation_deg[2],
        dt.x.abs() / s.translation_m[0],
        dt.y.abs() / s.translation_m[1],
        dt.z.abs() / s.translation_m[2],
    ];
    TruthErrors {
        focal_rel,
        pp_px,
        intr_sigmas,
        rot_deg,
        trans_rel,
        ext_sigmas,
    }
}

/// Asserts the accuracy bounds (focal < 0.2 %, principal point < 0.5 px, extrinsic rotation
/// < 0.1°, translation < 1 % of the baseline) and the 3σ consistency.
pub fn assert_truth(label: &str, cal: &Calibration, truth: &SynthRig) {
    let e = compare(cal, truth);
    eprintln!(
        "{label}: {e:#?}\nwarnings: {:#?}\nrms thermal {:?} rgb {:?} pairs {}",
        cal.warnings,
        cal.cameras[0].as_ref().map(|r| r.rms_px),
        cal.cameras[1].as_ref().map(|r| r.rms_px),
        cal.pairs_used
    );
    for camera in Camera::BOTH {
        let k = camera.index();
        for (axis, v) in ["fx", "fy"].iter().zip(e.focal_rel[k]) {
            assert!(
                v < 0.002,
                "{label}: {} {axis} error {:.4} %, want < 0.2 %",
                camera.name(),
                100.0 * v
            );
        }
        for (axis, v) in ["cx", "cy"].iter().zip(e.pp_px[k]) {
            assert!(
                v < 0.5,
                "{label}: {} {axis} error {v:.3} px, want < 0.5 px",
                camera.name()
            );
        }
        for (axis, v) in ["fx", "fy", "cx", "cy"].iter().zip(e.intr_sigmas[k]) {
            assert!(
                v < 3.0,
                "{label}: {} true {axis} is {v:.2}σ from the estimate, want inside 3σ",
                camera.name()
            );
        }
    }
    assert!(
        e.rot_deg < 0.1,
        "{label}: extrinsic rotation error {:.4}°, want < 0.1°",
        e.rot_deg
    );
    assert!(
        e.trans_rel < 0.01,
        "{label}: extrinsic translation error {:.3} % of baseline, want < 1 %",
        100.0 * e.trans_rel
    );
    for (i, v) in e.ext_sigmas.iter().enumerate() {
        assert!(
            *v < 3.0,
            "{label}: extrinsic component {i} (rx, ry, rz, tx, ty, tz) is {v:.2}σ off, want inside 3σ"
        );
    }
}

/// A real data set in `shared/data/` (beside the clone, or under `$S3TIR_SHARED_DIR`).
pub fn shared_data(set: &str) -> PathBuf {
    std::env::var_os("S3TIR_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data")
        .join(set)
}
