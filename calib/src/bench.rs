//! Benchmarks (`s3tir-calib bench`) against OpenCV in the same process.
//!
//! * [`run_real`] (`bench --real DIR`): a real board folder. Per image, on one core and with
//!   the decoded image in memory, s3tir's detector next to OpenCV's `findChessboardCornersSB`
//!   (plain grey; `EXHAUSTIVE | ACCURACY` as a user calls it, and `EXHAUSTIVE` alone as
//!   s3tir's front end does) and the classic `findChessboardCorners` + `cornerSubPix` (image,
//!   then its inverse); s3tir's detection as the calibrate command runs it (all images in
//!   parallel, decode included); then the solve on s3tir's detections: the whole calibration
//!   after detection next to OpenCV's `calibrateCamera` ×2 + `stereoCalibrate`.
//! * [`run`] (`bench`): a synthetic Lepton 160×120 + 1280×720 set of N pairs; our detection +
//!   per-camera init + joint LM, next to OpenCV's `stereoCalibrate` (with
//!   `CALIB_USE_INTRINSIC_GUESS` from `calibrateCamera` per camera, OpenCV's default
//!   termination criteria; our pipeline's own init stops after 20 iterations) on the *same*
//!   detections. Detection is shared, so the end-to-end ratio is (detection + ours) /
//!   (detection + OpenCV init + stereoCalibrate); the solve-only ratio is printed too.
//!
//! One run, wall-clock; no timing asserts anywhere.

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};

use opencv::calib3d;

use crate::detect::board::{BoardSpec, Camera, list_views};
use crate::detect::chessboard::{classic_sub_pix, mat_from_luma, read_grey};
use crate::detect::frontend::{BoardDetection, detect_board};
use crate::detect::scalar::load_scalar;
use crate::detect::views::DetectedSet;
use crate::error::{CalibError, cv};
use crate::progress::Progress;
use crate::solve::pipeline::{
    PipelineOptions, ViewCorners, calibrate_detections, cv_points, detect_folder, model_from_opencv,
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

/// Runs the benchmark in `dir` (created; images written there); `apriltags` prints tags on the
/// synthetic board; `progress` hears detection.
pub fn run(
    dir: &Path,
    pairs: usize,
    seed: u64,
    apriltags: bool,
    progress: &dyn Progress,
) -> Result<BenchFigures, CalibError> {
    let rig = synth::rig(synth::lepton(), synth::rgb_720p());
    let mut board = synth::default_board();
    if apriltags {
        // One tag per uncoated square (the board module's layout).
        board.apriltag_ids = (0..(board.cols() + 1) * (board.rows() + 1) / 2).collect();
    }
    let opts = SynthOptions::new(board, pairs, seed);
    let t0 = Instant::now();
    synth::write_board_folder(dir, &rig, &opts)?;
    let render_s = t0.elapsed().as_secs_f64();
    let set = detect_folder(dir, progress)?;
    let t_ours = Instant::now();
    let cal = calibrate_detections(&set, &PipelineOptions::default())?;
    let ours_solve_s = t_ours.elapsed().as_secs_f64();
    let peer = opencv_peer(&set)?;
    Ok(BenchFigures {
        pairs,
        pairs_detected: peer.pairs,
        render_s,
        detection_s: set.detection_wall_s,
        ours_solve_s,
        ours_lm_s: cal.solve_wall_s,
        ours_rms_px: cal.joint_rms_px,
        opencv_solve_s: peer.solve_s,
        opencv_stereo_s: peer.stereo_s,
        opencv_rms_px: peer.stereo_rms_px,
    })
}

/// OpenCV's own solve on a detected set: `calibrateCamera` per camera on every view with the
/// board, then `stereoCalibrate` on the pairs (`CALIB_USE_INTRINSIC_GUESS`, OpenCV's default
/// termination criteria).
#[derive(Debug, Clone, Copy)]
pub struct PeerFigures {
    pub pairs: usize,
    /// `calibrateCamera` ×2 + `stereoCalibrate`, seconds.
    pub solve_s: f64,
    /// `stereoCalibrate` alone, seconds.
    pub stereo_s: f64,
    /// `calibrateCamera`'s RMS per camera (px, over every corner).
    pub mono_rms_px: [f64; 2],
    pub stereo_rms_px: f64,
}

/// Runs [`PeerFigures`] on `set`'s corners as they are (`corners_px` of each detection).
pub fn opencv_peer(set: &DetectedSet) -> Result<PeerFigures, CalibError> {
    let t1 = Instant::now();
    let object = set.board.object_points_m();
    // stereoCalibrate takes one board point list per pair for both cameras: pairs of whole
    // boards only (a partial AprilTag board still calibrates its own camera below).
    let whole = |d: &BoardDetection| d.corner_ids.len() == object.len();
    let pairs_v: Vec<(ViewCorners, ViewCorners)> = set
        .views
        .iter()
        .filter_map(|v| match &v.detections {
            [Some(t), Some(r)] if whole(t) && whole(r) => Some((
                (t.corners_px.as_slice(), t.corner_ids.as_slice()),
                (r.corners_px.as_slice(), r.corner_ids.as_slice()),
            )),
            _ => None,
        })
        .collect();
    // OpenCV's default criteria for calibrateCamera and stereoCalibrate (30 iterations, ε = DBL_EPSILON).
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        30,
        f64::EPSILON,
    )
    .map_err(cv("TermCriteria"))?;
    let mut ks = Vec::new();
    let mut mono_rms_px = [f64::NAN; 2];
    for camera in Camera::BOTH {
        let views: Vec<ViewCorners> = set
            .views
            .iter()
            .filter_map(|v| {
                v.detections[camera.index()]
                    .as_ref()
                    .map(|d| (d.corners_px.as_slice(), d.corner_ids.as_slice()))
            })
            .collect();
        let (obj, img) = cv_points(&object, &views);
        let (w, h) = set.image_size[camera.index()].unwrap_or((1, 1));
        let mut k = Mat::default();
        let mut d = Mat::default();
        let mut r = Vector::<Mat>::new();
        let mut t = Vector::<Mat>::new();
        mono_rms_px[camera.index()] = calib3d::calibrate_camera(
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
            path: set.dir.clone(),
            reason: "the benchmark needs both cameras".into(),
        })?;
    let (mut r, mut t, mut e, mut f) = (
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
    );
    let size = set.image_size[0].unwrap_or((1, 1));
    let t_stereo = Instant::now();
    let stereo_rms_px = calib3d::stereo_calibrate(
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
        calib3d::CALIB_USE_INTRINSIC_GUESS,
        criteria,
    )
    .map_err(cv("stereoCalibrate"))?;
    let stereo_s = t_stereo.elapsed().as_secs_f64();
    let solve_s = t1.elapsed().as_secs_f64();
    let _ = model_from_opencv(&k1, &d1, size)?;
    Ok(PeerFigures {
        pairs: pairs_v.len(),
        solve_s,
        stereo_s,
        mono_rms_px,
        stereo_rms_px,
    })
}

/// One detector over one camera's images: boards found and seconds per image.
#[derive(Debug, Clone)]
pub struct DetectorRun {
    pub detector: &'static str,
    pub found: usize,
    pub seconds: Vec<f64>,
}

impl DetectorRun {
    fn new(detector: &'static str) -> Self {
        Self {
            detector,
            found: 0,
            seconds: Vec::new(),
        }
    }

    /// Median seconds per image.
    pub fn median_s(&self) -> f64 {
        let mut s = self.seconds.clone();
        s.sort_by(f64::total_cmp);
        match s.len() {
            0 => f64::NAN,
            n if n % 2 == 1 => s[n / 2],
            n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
        }
    }

    pub fn total_s(&self) -> f64 {
        self.seconds.iter().sum()
    }
}

/// One camera's per-image detection figures.
#[derive(Debug, Clone)]
pub struct CameraDetection {
    pub camera: Camera,
    pub images: usize,
    pub image_size: Option<(u32, u32)>,
    /// s3tir; OpenCV SB with `EXHAUSTIVE | ACCURACY` (a user's call) and with `EXHAUSTIVE`
    /// only (s3tir's first detector); OpenCV's classic detector; in that order.
    pub runs: Vec<DetectorRun>,
}

/// Figures of [`run_real`].
#[derive(Debug, Clone)]
pub struct RealBench {
    pub dir: PathBuf,
    pub cameras: Vec<CameraDetection>,
    /// s3tir's detection of every image as `s3tir-calib DIR` runs it (rayon over images,
    /// decode included), seconds, and the worker threads it had.
    pub detection_parallel_s: f64,
    pub threads: usize,
    /// `calibrate_detections` (everything after detection), seconds.
    pub ours_solve_s: f64,
    /// The final joint LM + covariance alone, seconds.
    pub ours_joint_s: f64,
    pub ours_mono_rms_px: [f64; 2],
    pub ours_joint_rms_px: f64,
    pub pairs_found: usize,
    pub pairs_used: usize,
    pub opencv: PeerFigures,
}

const SB_FLAGS: i32 = calib3d::CALIB_CB_EXHAUSTIVE | calib3d::CALIB_CB_ACCURACY;
const CLASSIC_FLAGS: i32 = calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE;

/// OpenCV's classic detector as a user runs it on a board of either polarity: the image, then
/// its inverse, then `cornerSubPix` (11 × 11 window) on a hit.
fn opencv_classic(grey: &Mat, pattern: Size) -> Result<bool, CalibError> {
    let mut corners = Vector::<Point2f>::new();
    let mut found = calib3d::find_chessboard_corners(grey, pattern, &mut corners, CLASSIC_FLAGS)
        .map_err(cv("findChessboardCorners"))?;
    if !found {
        let mut inv = Mat::default();
        opencv::core::bitwise_not_def(grey, &mut inv).map_err(cv("bitwise_not"))?;
        found = calib3d::find_chessboard_corners(&inv, pattern, &mut corners, CLASSIC_FLAGS)
            .map_err(cv("findChessboardCorners"))?;
    }
    if found {
        classic_sub_pix(grey, &mut corners)?;
    }
    Ok(found)
}

/// The real-set benchmark (module docs) on board folder `dir` (`board.toml`, `thermal/`,
/// `rgb/`). `progress` hears the per-image pass, then detection.
pub fn run_real(dir: &Path, progress: &dyn Progress) -> Result<RealBench, CalibError> {
    let board = BoardSpec::load(&dir.join("board.toml"))?;
    let (files, _) = list_views(dir)?;
    let pattern = Size::new(board.cols() as i32, board.rows() as i32);
    let threads_before = opencv::core::get_num_threads().map_err(cv("getNumThreads"))?;
    // One core per image for every detector: the product parallelises over images.
    opencv::core::set_num_threads(1).map_err(cv("setNumThreads"))?;
    let total: usize = files.iter().map(|f| f.files.iter().flatten().count()).sum();
    progress.start("benchmarking images", Some(total as u64));
    let mut cameras = Vec::new();
    let per_image = (|| -> Result<(), CalibError> {
        for camera in Camera::BOTH {
            let mut runs = vec![
                DetectorRun::new("s3tir"),
                DetectorRun::new("OpenCV SB (EXHAUSTIVE | ACCURACY)"),
                DetectorRun::new("OpenCV SB (EXHAUSTIVE)"),
                DetectorRun::new("OpenCV classic + cornerSubPix, both polarities"),
            ];
            let mut images = 0;
            let mut image_size = None;
            for path in files
                .iter()
                .filter_map(|f| f.files[camera.index()].as_ref())
            {
                progress.advance(1);
                let Ok(scalar) =
                    load_scalar(path, camera == Camera::Thermal, board.thermal_palette)
                else {
                    continue;
                };
                let grey = mat_from_luma(&read_grey(path)?)?;
                images += 1;
                image_size.get_or_insert((scalar.width_px, scalar.height_px));
                let t = Instant::now();
                let ours = detect_board(&scalar, &board)?;
                runs[0].seconds.push(t.elapsed().as_secs_f64());
                runs[0].found += usize::from(ours.is_ok());
                for (run, flags) in [(1, SB_FLAGS), (2, calib3d::CALIB_CB_EXHAUSTIVE)] {
                    let mut corners = Vector::<Point2f>::new();
                    let t = Instant::now();
                    let sb =
                        calib3d::find_chessboard_corners_sb(&grey, pattern, &mut corners, flags)
                            .map_err(cv("findChessboardCornersSB"))?;
                    runs[run].seconds.push(t.elapsed().as_secs_f64());
                    runs[run].found += usize::from(sb);
                }
                let t = Instant::now();
                let classic = opencv_classic(&grey, pattern)?;
                runs[3].seconds.push(t.elapsed().as_secs_f64());
                runs[3].found += usize::from(classic);
            }
            cameras.push(CameraDetection {
                camera,
                images,
                image_size,
                runs,
            });
        }
        Ok(())
    })();
    progress.finish();
    opencv::core::set_num_threads(threads_before).map_err(cv("setNumThreads"))?;
    per_image?;
    let mut set = detect_folder(dir, progress)?;
    let t = Instant::now();
    let cal = calibrate_detections(&set, &PipelineOptions::default())?;
    let ours_solve_s = t.elapsed().as_secs_f64();
    // OpenCV solves on the corners s3tir's calibration used (each camera's chosen refinement).
    for (k, result) in cal.cameras.iter().enumerate() {
        if let Some(choice) = result.as_ref().and_then(|c| c.refinement.as_ref()) {
            for d in set
                .views
                .iter_mut()
                .filter_map(|v| v.detections[k].as_mut())
            {
                d.choose(choice.kept);
            }
        }
    }
    let opencv = opencv_peer(&set)?;
    let mono = |k: usize| {
        cal.cameras[k]
            .as_ref()
            .map_or(f64::NAN, |c| c.mono_rms_all_px)
    };
    Ok(RealBench {
        dir: dir.to_path_buf(),
        cameras,
        detection_parallel_s: set.detection_wall_s,
        threads: rayon::current_num_threads(),
        ours_solve_s,
        ours_joint_s: cal.solve_wall_s,
        ours_mono_rms_px: [mono(0), mono(1)],
        ours_joint_rms_px: cal.joint_rms_px,
        pairs_found: cal.pairs_found,
        pairs_used: cal.pairs_used,
        opencv,
    })
}

impl fmt::Display for RealBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "{}", self.dir.display())?;
        writeln!(
            f,
            "detection per image (one core, decoded image in memory):"
        )?;
        writeln!(
            f,
            "  {:<8} {:<46} {:>7} {:>10} {:>9} {:>8}",
            "camera", "detector", "found", "median ms", "total s", "× s3tir"
        )?;
        for c in &self.cameras {
            let ours = c.runs.first().map_or(f64::NAN, DetectorRun::total_s);
            let size = c
                .image_size
                .map_or(String::new(), |(w, h)| format!(" {w}x{h}"));
            for (i, r) in c.runs.iter().enumerate() {
                let camera = if i == 0 {
                    format!("{}{size}", c.camera.name())
                } else {
                    String::new()
                };
                writeln!(
                    f,
                    "  {:<8} {:<46} {:>3}/{:<3} {:>10.1} {:>9.2} {:>8.2}",
                    camera,
                    r.detector,
                    r.found,
                    c.images,
                    1e3 * r.median_s(),
                    r.total_s(),
                    r.total_s() / ours
                )?;
            }
        }
        let images: usize = self.cameras.iter().map(|c| c.images).sum();
        writeln!(
            f,
            "s3tir detection as `s3tir-calib DIR` runs it ({} threads, decode included): {:.2} s for {} images",
            self.threads, self.detection_parallel_s, images
        )?;
        writeln!(
            f,
            "solve on s3tir's detections ({} pairs; {} consistent):",
            self.pairs_found, self.pairs_used
        )?;
        writeln!(
            f,
            "  s3tir  (init + mono per refinement + pair tests + joint LM + covariance): {:.3} s (joint LM + covariance {:.3} s); mono RMS thermal {:.3} px, rgb {:.3} px; joint RMS {:.3} px",
            self.ours_solve_s,
            self.ours_joint_s,
            self.ours_mono_rms_px[0],
            self.ours_mono_rms_px[1],
            self.ours_joint_rms_px
        )?;
        write!(
            f,
            "  OpenCV (calibrateCamera x2 + stereoCalibrate on every pair):               {:.3} s (stereoCalibrate {:.3} s); mono RMS thermal {:.3} px, rgb {:.3} px; stereo RMS {:.3} px",
            self.opencv.solve_s,
            self.opencv.stereo_s,
            self.opencv.mono_rms_px[0],
            self.opencv.mono_rms_px[1],
            self.opencv.stereo_rms_px
        )
    }
}
