//! End-to-end benchmark (`s3tir-calib bench`): a synthetic Lepton 160×120 + 1280×720 set of N
//! pairs; our detection + per-camera init + joint LM, next to OpenCV's `stereoCalibrate`
//! (with `CALIB_USE_INTRINSIC_GUESS` from `calibrateCamera` per camera, OpenCV's default
//! termination criteria; our pipeline's own init stops after 20 iterations) on the *same*
//! detections. Detection is shared, so the end-to-end ratio is
//! (detection + ours) / (detection + OpenCV init + stereoCalibrate); the solve-only ratio is
//! printed too. One run, wall-clock; no timing asserts anywhere.

use std::fmt;
use std::path::Path;
use std::time::Instant;

use glam::DVec2;
use opencv::core::{Mat, Size, TermCriteria, TermCriteria_Type, Vector};

use crate::board::Camera;
use crate::error::CalibError;
use crate::pipeline::{
    PipelineOptions, calibrate_detections, cv_points, detect_folder, model_from_opencv,
};
use crate::synth::{self, SynthOptions};

/// Benchmark figures.
#[derive(Debug, Clone, Copy)]
pub struct BenchFigures {
    pub pairs: usize,
    pub pairs_detected: usize,
    pub render_s: f64,
    pub detection_s: f64,
    pub ours_solve_s: f64,
    /// Our joint LM alone (after the per-camera OpenCV init).
    pub ours_lm_s: f64,
    pub ours_rms_px: f64,
    pub opencv_solve_s: f64,
    /// `stereoCalibrate` alone (after `calibrateCamera` ×2).
    pub opencv_stereo_s: f64,
    pub opencv_rms_px: f64,
}

impl BenchFigures {
    pub fn end_to_end_ratio(&self) -> f64 {
        (self.detection_s + self.ours_solve_s) / (self.detection_s + self.opencv_solve_s)
    }
    pub fn solve_ratio(&self) -> f64 {
        self.ours_solve_s / self.opencv_solve_s
    }
    pub fn joint_stage_ratio(&self) -> f64 {
        self.ours_lm_s / self.opencv_stereo_s
    }
}

impl fmt::Display for BenchFigures {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "synthetic pairs: {} generated, {} detected in both cameras (render {:.2} s, not timed)",
            self.pairs, self.pairs_detected, self.render_s
        )?;
        writeln!(
            f,
            "detection (both cameras, shared):        {:.3} s",
            self.detection_s
        )?;
        writeln!(
            f,
            "ours:   calibrateCamera x2 + joint LM         {:.3} s (LM {:.3} s), joint RMS {:.4} px",
            self.ours_solve_s, self.ours_lm_s, self.ours_rms_px
        )?;
        writeln!(
            f,
            "OpenCV: calibrateCamera x2 + stereoCalibrate  {:.3} s (stereoCalibrate {:.3} s), stereo RMS {:.4} px",
            self.opencv_solve_s, self.opencv_stereo_s, self.opencv_rms_px
        )?;
        writeln!(
            f,
            "end-to-end ratio ours/OpenCV (detection + solve): {:.3}",
            self.end_to_end_ratio()
        )?;
        writeln!(
            f,
            "solve ratio ours/OpenCV (init + joint stage):     {:.3}",
            self.solve_ratio()
        )?;
        write!(
            f,
            "joint-stage ratio (our LM / stereoCalibrate):     {:.3}",
            self.joint_stage_ratio()
        )
    }
}

fn cv(operation: &'static str) -> impl FnOnce(opencv::Error) -> CalibError {
    move |source| CalibError::OpenCv { operation, source }
}

/// Runs the benchmark in `dir` (created; images written there).
pub fn run(dir: &Path, pairs: usize, seed: u64) -> Result<BenchFigures, CalibError> {
    let rig = synth::rig(synth::lepton(), synth::rgb_720p());
    let opts = SynthOptions::new(synth::default_board(), pairs, seed);
    let t0 = Instant::now();
    synth::write_board_folder(dir, &rig, &opts)?;
    let render_s = t0.elapsed().as_secs_f64();
    let set = detect_folder(dir, true)?;
    let t_ours = Instant::now();
    let cal = calibrate_detections(&set, &PipelineOptions::default())?;
    let ours_solve_s = t_ours.elapsed().as_secs_f64();
    // OpenCV peer on the same detections (pairs only, as stereoCalibrate needs).
    let t1 = Instant::now();
    let pairs_v: Vec<(&[DVec2], &[DVec2])> = set
        .views
        .iter()
        .filter_map(|v| match &v.detections {
            [Some(t), Some(r)] => Some((t.corners_px.as_slice(), r.corners_px.as_slice())),
            _ => None,
        })
        .collect();
    let object = set.board.object_points_m();
    // OpenCV's default criteria for calibrateCamera and stereoCalibrate (30 iterations, ε = DBL_EPSILON).
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        30,
        f64::EPSILON,
    )
    .map_err(cv("TermCriteria"))?;
    let mut ks = Vec::new();
    for camera in Camera::BOTH {
        let views: Vec<&[DVec2]> = set
            .views
            .iter()
            .filter_map(|v| {
                v.detections[camera.index()]
                    .as_ref()
                    .map(|d| d.corners_px.as_slice())
            })
            .collect();
        let (obj, img) = cv_points(&object, &views);
        let (w, h) = set.image_size[camera.index()].unwrap_or((1, 1));
        let mut k = Mat::default();
        let mut d = Mat::default();
        let mut r = Vector::<Mat>::new();
        let mut t = Vector::<Mat>::new();
        opencv::calib3d::calibrate_camera(
            &obj,
            &img,
            Size::new(w as i32, h as i32),
            &mut k,
            &mut d,
            &mut r,
            &mut t,
            0,
            criteria,
        )
        .map_err(cv("calibrateCamera"))?;
        ks.push((k, d));
    }
    let (obj, img_t) = cv_points(&object, &pairs_v.iter().map(|p| p.0).collect::<Vec<_>>());
    let (_, img_r) = cv_points(&object, &pairs_v.iter().map(|p| p.1).collect::<Vec<_>>());
    let [(mut k1, mut d1), (mut k2, mut d2)] =
        <[(Mat, Mat); 2]>::try_from(ks).map_err(|_| CalibError::NothingUsable {
            path: dir.to_path_buf(),
            reason: "benchmark needs both cameras".into(),
        })?;
    let (mut r, mut t, mut e, mut f) = (
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
    );
    let size = set.image_size[0].unwrap_or((1, 1));
    let t_stereo = Instant::now();
    let opencv_rms = opencv::calib3d::stereo_calibrate(
        &obj,
        &img_t,
        &img_r,
        &mut k1,
        &mut d1,
        &mut k2,
        &mut d2,
        Size::new(size.0 as i32, size.1 as i32),
        &mut r,
        &mut t,
        &mut e,
        &mut f,
        opencv::calib3d::CALIB_USE_INTRINSIC_GUESS,
        criteria,
    )
    .map_err(cv("stereoCalibrate"))?;
    let opencv_solve_s = t1.elapsed().as_secs_f64();
    let opencv_stereo_s = t_stereo.elapsed().as_secs_f64();
    let _ = model_from_opencv(&k1, &d1, size)?;
    Ok(BenchFigures {
        pairs,
        pairs_detected: pairs_v.len(),
        render_s,
        detection_s: set.detection_wall_s,
        ours_solve_s,
        ours_lm_s: cal.solve_wall_s,
        ours_rms_px: cal.joint_rms_px,
        opencv_solve_s,
        opencv_stereo_s,
        opencv_rms_px: opencv_rms,
    })
}
