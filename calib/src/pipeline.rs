//! Board folder → detections → per-camera OpenCV initialisation → one joint LM → result with
//! warnings. Detection and solving are separate steps ([`detect_folder`],
//! [`calibrate_detections`]) so the benchmark can time them apart.
//!
//! RMS figures follow OpenCV: `sqrt(Σ|r|² / N)` over corners (not per axis). The joint RMS
//! is over every inlier corner of both cameras (paired and unpaired views).

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{DQuat, DVec2, DVec3};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use serde::Serialize;

use crate::board::{BoardSpec, Camera, FileProblem, ViewFiles, list_views};
use crate::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::error::CalibError;
use crate::frontend::ScalarImage;
use crate::frontend::{
    BoardDetection, DetectFailure, SourceKind, ThermalPolarity, detect_board, load_scalar,
    rotate_180,
};
use crate::geometry::Rigid3;
use crate::session::{SessionOptions, SessionViews};
use crate::solve::{
    ExtrinsicSigma, IntrinsicSigma, IterationLog, Observation, PoseFrame, Problem, RejectedCorner,
    SolveOptions, solve,
};

/// One view's files and detections.
#[derive(Debug, Clone)]
pub struct DetectedView {
    pub key: String,
    pub files: [Option<PathBuf>; 2],
    pub detections: [Option<BoardDetection>; 2],
}

/// Everything detection produced for a folder.
#[derive(Debug, Clone)]
pub struct DetectedSet {
    pub dir: PathBuf,
    pub board: BoardSpec,
    pub views: Vec<DetectedView>,
    /// Image size per camera (`None`: no readable image).
    pub image_size: [Option<(u32, u32)>; 2],
    /// Image counts per camera (files listed).
    pub images: [usize; 2],
    pub problems: Vec<FileProblem>,
    /// How thermal ordering was fixed, in words.
    pub polarity_note: String,
    pub source_kinds: Vec<(Camera, SourceKind)>,
    pub detection_wall_s: f64,
    /// Input notes that become warnings (e.g. a truncated session).
    pub notes: Vec<String>,
}

/// Options of a run.
#[derive(Debug, Clone, Copy, Default)]
pub struct PipelineOptions {
    pub solve: SolveOptions,
    /// Draw an indicatif progress bar over detection.
    pub progress: bool,
}

fn problem(path: &Path, reason: impl Into<String>) -> FileProblem {
    FileProblem {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// True when `path` names a recorded session (`.mcap`).
pub fn is_session(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}

/// Loads `board.toml` and detects the board in every image of `dir`. A session path
/// (`.mcap`) is refused with [`CalibError::SessionNeedsBoard`]: use [`detect_session`].
pub fn detect_folder(dir: &Path, progress: bool) -> Result<DetectedSet, CalibError> {
    if is_session(dir) {
        return Err(CalibError::SessionNeedsBoard {
            path: dir.to_path_buf(),
        });
    }
    let board = BoardSpec::load(&dir.join("board.toml"))?;
    let (files, mut problems) = list_views(dir)?;
    let thermal_palette = board.thermal_palette;
    detect_views(
        dir,
        board,
        files,
        &mut problems,
        progress,
        |path, camera| load_scalar(path, camera == Camera::Thermal, thermal_palette),
    )
}

/// Reads a recorded session (see [`crate::session`]) and detects the board described by
/// `board_toml` in its views.
pub fn detect_session(
    session: &Path,
    board_toml: &Path,
    session_opts: &SessionOptions,
    progress: bool,
) -> Result<DetectedSet, CalibError> {
    let board = BoardSpec::load(board_toml)?;
    let SessionViews {
        views,
        images,
        mut problems,
        notes,
    } = crate::session::read_views(session, session_opts)?;
    let mut set = detect_views(
        session,
        board,
        views,
        &mut problems,
        progress,
        |name, camera| images.load(name, camera),
    )?;
    set.notes.extend(notes);
    Ok(set)
}

/// Detection over listed views; `load` decodes a listed image (a file, or a session frame).
pub fn detect_views(
    dir: &Path,
    board: BoardSpec,
    files: Vec<ViewFiles>,
    problems: &mut Vec<FileProblem>,
    progress: bool,
    mut load: impl FnMut(&Path, Camera) -> Result<ScalarImage, CalibError>,
) -> Result<DetectedSet, CalibError> {
    let start = Instant::now();
    let total: usize = files.iter().map(|v| v.files.iter().flatten().count()).sum();
    let bar = if progress {
        let b = indicatif::ProgressBar::new(total as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "detecting {bar:40} {pos}/{len} images {elapsed}/{eta} {msg}",
        ) {
            b.set_style(style);
        }
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let mut image_size: [Option<(u32, u32)>; 2] = [None, None];
    let mut images = [0usize; 2];
    let mut source_kinds = Vec::new();
    let mut views = Vec::with_capacity(files.len());
    for vf in files {
        let mut detections: [Option<BoardDetection>; 2] = [None, None];
        for camera in Camera::BOTH {
            let Some(path) = &vf.files[camera.index()] else {
                continue;
            };
            images[camera.index()] += 1;
            bar.set_message(
                path.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default(),
            );
            bar.inc(1);
            let img = match load(path, camera) {
                Ok(i) => i,
                Err(e) => {
                    problems.push(problem(path, format!("unreadable: {e}")));
                    continue;
                }
            };
            let size = (img.width_px, img.height_px);
            match image_size[camera.index()] {
                None => image_size[camera.index()] = Some(size),
                Some(s) if s != size => {
                    problems.push(problem(
                        path,
                        format!(
                            "wrong size {}x{}: the {} camera's images are {}x{}",
                            size.0,
                            size.1,
                            camera.name(),
                            s.0,
                            s.1
                        ),
                    ));
                    continue;
                }
                Some(_) => {}
            }
            if !source_kinds.contains(&(camera, img.source)) {
                source_kinds.push((camera, img.source));
            }
            let span = tracing::trace_span!("detect", file = %path.display());
            let _g = span.enter();
            match detect_board(&img, &board)? {
                Ok(d) => detections[camera.index()] = Some(d),
                Err(DetectFailure::NotFound) => problems.push(problem(
                    path,
                    format!(
                        "no {}x{} board found (both polarities, SB and classic detectors)",
                        board.cols(),
                        board.rows()
                    ),
                )),
                Err(DetectFailure::Ambiguous(why)) => problems.push(problem(
                    path,
                    format!("ambiguous detection rejected: {why}"),
                )),
            }
        }
        views.push(DetectedView {
            key: vf.key,
            files: vf.files,
            detections,
        });
    }
    bar.finish_and_clear();
    let polarity_note = resolve_thermal_order(&board, &mut views, problems);
    Ok(DetectedSet {
        dir: dir.to_path_buf(),
        board,
        views,
        image_size,
        images,
        problems: std::mem::take(problems),
        polarity_note,
        source_kinds,
        detection_wall_s: start.elapsed().as_secs_f64(),
        notes: Vec::new(),
    })
}

/// Makes thermal corner order agree with RGB (see `frontend` docs): fixed polarity from
/// `board.toml`, or for `auto` a vote over pairs on whether corner 0 → corner N points the
/// same way in both images. Pairs that disagree with the majority are unpaired (reported).
fn resolve_thermal_order(
    board: &BoardSpec,
    views: &mut [DetectedView],
    problems: &mut Vec<FileProblem>,
) -> String {
    if board.is_colour_symmetric() {
        return "board is colour-symmetric (cols + rows even): both cameras ordered with corner 0 nearest the image's top-left".into();
    }
    let direction = |d: &BoardDetection| {
        let n = d.corners_px.len();
        (d.corners_px[n - 1] - d.corners_px[0]).normalize_or_zero()
    };
    let (rotate, note) = match board.thermal_polarity {
        ThermalPolarity::CoatedDark => (
            false,
            "thermal_polarity = coated_dark (board.toml)".to_string(),
        ),
        ThermalPolarity::CoatedBright => (
            true,
            "thermal_polarity = coated_bright (board.toml)".to_string(),
        ),
        ThermalPolarity::Auto => {
            let (mut dark, mut bright) = (0usize, 0usize);
            for v in views.iter() {
                if let [Some(t), Some(r)] = &v.detections {
                    if direction(t).dot(direction(r)) > 0.0 {
                        dark += 1;
                    } else {
                        bright += 1;
                    }
                }
            }
            if dark + bright == 0 {
                (false, "thermal_polarity = auto with no pairs: assumed coated_dark (ordering does not matter for one camera)".into())
            } else {
                (
                    bright > dark,
                    format!(
                        "thermal_polarity = auto: {} by vote over pairs ({dark} say coated_dark, {bright} coated_bright)",
                        if bright > dark {
                            "coated_bright"
                        } else {
                            "coated_dark"
                        }
                    ),
                )
            }
        }
    };
    for v in views.iter_mut() {
        if rotate && let Some(t) = v.detections[0].as_mut() {
            rotate_180(t);
        }
        if let [Some(t), Some(r)] = &v.detections
            && direction(t).dot(direction(r)) <= 0.0
        {
            if let Some(path) = &v.files[0] {
                problems.push(problem(
                    path,
                    "corner order disagrees with its RGB pair (polarity differs from the session's): used for thermal intrinsics only, not as a pair",
                ));
            }
            // Keep it as a thermal-only view under a distinct key.
            v.key = format!("{}#thermal-only", v.key);
            v.detections[1] = None;
        }
    }
    note
}

/// Result for one camera.
#[derive(Debug, Clone, Serialize)]
pub struct CameraResult {
    pub camera: Camera,
    pub model: CameraModel,
    pub sigma: IntrinsicSigma,
    pub images: usize,
    pub views_found: usize,
    pub views_used: usize,
    pub rms_px: f64,
    /// RMS over every detected corner including the rejected ones (px).
    pub rms_all_px: f64,
    /// OpenCV `calibrateCamera` RMS of the initialisation (px).
    pub init_rms_px: f64,
    /// Per view: (key, RMS px, inliers).
    pub per_view: Vec<ViewRms>,
}

/// A view's reprojection error for one camera.
#[derive(Debug, Clone, Serialize)]
pub struct ViewRms {
    pub key: String,
    pub rms_px: f64,
    pub corners_used: usize,
    pub tilt_deg: f64,
}

/// A corner residual for plots: observed position and residual (predicted − observed).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct CornerResidual {
    pub observed_px: DVec2,
    pub residual_px: DVec2,
    pub inlier: bool,
}

/// The calibration outcome.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    pub board: BoardSpec,
    pub cameras: [Option<CameraResult>; 2],
    pub rgb_from_thermal: Option<Rigid3>,
    pub extrinsic_sigma: Option<ExtrinsicSigma>,
    pub joint_rms_px: f64,
    pub pairs_used: usize,
    pub warnings: Vec<String>,
    pub problems: Vec<FileProblem>,
    pub rejected: Vec<RejectedCorner>,
    pub iterations: Vec<IterationLog>,
    pub polarity_note: String,
    pub detection_wall_s: f64,
    pub solve_wall_s: f64,
    pub converged: bool,
    /// Per camera, every corner's residual (for the report's plots).
    #[serde(skip)]
    pub residuals: [Vec<CornerResidual>; 2],
    /// Keys of the views in solver order.
    pub view_keys: Vec<String>,
}

fn cv(operation: &'static str) -> impl FnOnce(opencv::Error) -> CalibError {
    move |source| CalibError::OpenCv { operation, source }
}

fn rigid_from_rvec_tvec(r: &Mat, t: &Mat) -> Result<Rigid3, CalibError> {
    let rv = DVec3::new(
        *r.at::<f64>(0).map_err(cv("rvec"))?,
        *r.at::<f64>(1).map_err(cv("rvec"))?,
        *r.at::<f64>(2).map_err(cv("rvec"))?,
    );
    let tv = DVec3::new(
        *t.at::<f64>(0).map_err(cv("tvec"))?,
        *t.at::<f64>(1).map_err(cv("tvec"))?,
        *t.at::<f64>(2).map_err(cv("tvec"))?,
    );
    Ok(Rigid3::new(DQuat::from_scaled_axis(rv), tv))
}

/// OpenCV camera matrix and distortion from a model.
pub fn opencv_k_dist(m: &CameraModel) -> Result<(Mat, Mat), CalibError> {
    let i = m.intrinsics;
    let d = m.distortion;
    let k = Mat::from_slice_2d(&[[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]])
        .map_err(cv("camera matrix"))?;
    let dist = Mat::from_slice(&[d.k1, d.k2, d.p1, d.p2, d.k3])
        .map_err(cv("distortion"))?
        .try_clone()
        .map_err(cv("distortion"))?;
    Ok((k, dist))
}

/// Model from OpenCV K and distortion.
pub fn model_from_opencv(k: &Mat, dist: &Mat, size: (u32, u32)) -> Result<CameraModel, CalibError> {
    let g = |r: i32, c: i32| k.at_2d::<f64>(r, c).copied().map_err(cv("K"));
    let d = |i: i32| {
        if i < dist.total() as i32 {
            dist.at::<f64>(i).copied().map_err(cv("dist"))
        } else {
            Ok(0.0)
        }
    };
    Ok(CameraModel {
        width_px: size.0,
        height_px: size.1,
        intrinsics: Intrinsics {
            fx: g(0, 0)?,
            fy: g(1, 1)?,
            cx: g(0, 2)?,
            cy: g(1, 2)?,
        },
        distortion: BrownConrady {
            k1: d(0)?,
            k2: d(1)?,
            p1: d(2)?,
            p2: d(3)?,
            k3: d(4)?,
        },
    })
}

/// OpenCV point vectors for detections.
pub fn cv_points(
    object: &[DVec3],
    views: &[&[DVec2]],
) -> (Vector<Vector<Point3f>>, Vector<Vector<Point2f>>) {
    let obj: Vector<Point3f> = object
        .iter()
        .map(|p| Point3f::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    let mut o = Vector::new();
    let mut i = Vector::new();
    for v in views {
        o.push(obj.clone());
        i.push(
            v.iter()
                .map(|p| Point2f::new(p.x as f32, p.y as f32))
                .collect::<Vector<Point2f>>(),
        );
    }
    (o, i)
}

fn plausible(m: &CameraModel) -> bool {
    let w = f64::from(m.width_px);
    let h = f64::from(m.height_px);
    let i = m.intrinsics;
    m.validate().is_ok()
        && i.fx > 0.1 * w
        && i.fx < 50.0 * w
        && (i.fy / i.fx - 1.0).abs() < 0.5
        && i.cx > 0.0
        && i.cx < w
        && i.cy > 0.0
        && i.cy < h
}

/// Per-camera initialisation: OpenCV `calibrateCamera` (≤ 20 iterations; k3 and tangential fixed at 0 with
/// fewer than 6 views), falling back to a 53° pinhole guess + `solvePnP` when OpenCV fails or
/// returns an implausible camera (e.g. all views fronto-parallel).
fn init_camera(
    object: &[DVec3],
    views: &[&[DVec2]],
    size: (u32, u32),
    warnings: &mut Vec<String>,
    name: &str,
) -> Result<(CameraModel, Vec<Rigid3>, f64), CalibError> {
    let (obj, img) = cv_points(object, views);
    let mut k = Mat::default();
    let mut dist = Mat::default();
    let mut rvecs = Vector::<Mat>::new();
    let mut tvecs = Vector::<Mat>::new();
    let flags = if views.len() < 6 {
        calib3d_flags_few()
    } else {
        0
    };
    // The joint LM refines everything afterwards: the init only has to land in its basin.
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        20,
        1e-6,
    )
    .map_err(cv("TermCriteria"))?;
    let res = opencv::calib3d::calibrate_camera(
        &obj,
        &img,
        Size::new(size.0 as i32, size.1 as i32),
        &mut k,
        &mut dist,
        &mut rvecs,
        &mut tvecs,
        flags,
        criteria,
    );
    if let Ok(rms) = res
        && rms.is_finite()
        && let Ok(model) = model_from_opencv(&k, &dist, size)
        && plausible(&model)
    {
        let poses = rvecs
            .iter()
            .zip(tvecs.iter())
            .map(|(r, t)| rigid_from_rvec_tvec(&r, &t))
            .collect::<Result<Vec<_>, _>>()?;
        return Ok((model, poses, rms));
    }
    warnings.push(format!(
        "{name}: OpenCV calibrateCamera gave no plausible initial camera ({}); started from a 53° pinhole guess",
        match res { Ok(r) => format!("RMS {r:.3} px"), Err(e) => e.to_string() }
    ));
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let model = CameraModel {
        width_px: size.0,
        height_px: size.1,
        intrinsics: Intrinsics {
            fx: w,
            fy: w,
            cx: (w - 1.0) / 2.0,
            cy: (h - 1.0) / 2.0,
        },
        distortion: BrownConrady::default(),
    };
    let (kk, dd) = opencv_k_dist(&model)?;
    let mut poses = Vec::new();
    for (o, i) in obj.iter().zip(img.iter()) {
        let mut r = Mat::default();
        let mut t = Mat::default();
        opencv::calib3d::solve_pnp(
            &o,
            &i,
            &kk,
            &dd,
            &mut r,
            &mut t,
            false,
            opencv::calib3d::SOLVEPNP_ITERATIVE,
        )
        .map_err(cv("solvePnP"))?;
        poses.push(rigid_from_rvec_tvec(&r, &t)?);
    }
    Ok((model, poses, f64::NAN))
}

fn calib3d_flags_few() -> i32 {
    opencv::calib3d::CALIB_FIX_K3 | opencv::calib3d::CALIB_ZERO_TANGENT_DIST
}

/// Averages rigid transforms (sign-aligned quaternion mean, component-wise median translation).
fn average_rigid(ts: &[Rigid3]) -> Rigid3 {
    let Some(first) = ts.first() else {
        return Rigid3::IDENTITY;
    };
    let mut q = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    for t in ts {
        let r = if t.rotation.dot(first.rotation) < 0.0 {
            -t.rotation
        } else {
            t.rotation
        };
        q += r;
    }
    let median = |f: fn(&DVec3) -> f64| {
        let mut v: Vec<f64> = ts.iter().map(|t| f(&t.translation_m)).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    Rigid3::new(
        q.normalize(),
        DVec3::new(median(|v| v.x), median(|v| v.y), median(|v| v.z)),
    )
}

fn tilt_deg(cam_from_board: &Rigid3) -> f64 {
    let n = cam_from_board.transform_vector(DVec3::Z);
    n.z.abs().clamp(0.0, 1.0).acos().to_degrees()
}

/// Solves the detections of a folder.
pub fn calibrate_detections(
    set: &DetectedSet,
    opts: &PipelineOptions,
) -> Result<Calibration, CalibError> {
    let mut warnings = set.notes.clone();
    let object = set.board.object_points_m();
    let mut cameras: [Option<CameraModel>; 2] = [None, None];
    let mut init_poses: [Vec<(usize, Rigid3)>; 2] = [Vec::new(), Vec::new()];
    let mut init_rms = [f64::NAN; 2];
    let mut views_found = [0usize; 2];
    for camera in Camera::BOTH {
        let k = camera.index();
        let idx: Vec<usize> = set
            .views
            .iter()
            .enumerate()
            .filter(|(_, v)| v.detections[k].is_some())
            .map(|(i, _)| i)
            .collect();
        views_found[k] = idx.len();
        if set.images[k] == 0 {
            continue;
        }
        let Some(size) = set.image_size[k] else {
            warnings.push(format!("{}: no readable image", camera.name()));
            continue;
        };
        if idx.len() < 3 {
            warnings.push(format!(
                "{}: the board was found in only {} of {} images; at least 3 are needed, camera left out",
                camera.name(),
                idx.len(),
                set.images[k]
            ));
            continue;
        }
        if idx.len() < 6 {
            warnings.push(format!(
                "{}: the board was found in only {} views: intrinsics (distortion especially) are weakly constrained",
                camera.name(),
                idx.len()
            ));
        }
        let views: Vec<&[DVec2]> = idx
            .iter()
            .filter_map(|&i| {
                set.views[i].detections[k]
                    .as_ref()
                    .map(|d| d.corners_px.as_slice())
            })
            .collect();
        let (model, poses, rms) = init_camera(&object, &views, size, &mut warnings, camera.name())?;
        cameras[k] = Some(model);
        init_rms[k] = rms;
        init_poses[k] = idx.into_iter().zip(poses).collect();
    }
    if cameras.iter().all(Option::is_none) {
        let reason = if set.problems.is_empty() {
            "no images in thermal/ or rgb/".to_string()
        } else {
            format!(
                "{} file problems (first: {}: {})",
                set.problems.len(),
                set.problems[0].path.display(),
                set.problems[0].reason
            )
        };
        return Err(CalibError::NothingUsable {
            path: set.dir.clone(),
            reason,
        });
    }
    let pose_of = |k: usize, view: usize| {
        init_poses[k]
            .iter()
            .find(|(v, _)| *v == view)
            .map(|(_, p)| *p)
    };
    // Views for the solver.
    let mut poses = Vec::new();
    let mut observations = Vec::new();
    let mut view_keys = Vec::new();
    let mut pair_extrinsics = Vec::new();
    for (vi, v) in set.views.iter().enumerate() {
        let t = if cameras[0].is_some() {
            pose_of(0, vi)
        } else {
            None
        };
        let r = if cameras[1].is_some() {
            pose_of(1, vi)
        } else {
            None
        };
        let (frame, pose) = match (t, r) {
            (Some(t), Some(r)) => {
                pair_extrinsics.push(r.compose(&t.inverse()));
                (PoseFrame::Thermal, t)
            }
            (Some(t), None) => (PoseFrame::Thermal, t),
            (None, Some(r)) => (PoseFrame::Rgb, r),
            (None, None) => continue,
        };
        let index = poses.len();
        poses.push((frame, pose));
        view_keys.push(v.key.clone());
        for (k, present) in [t.is_some(), r.is_some()].into_iter().enumerate() {
            if present && let Some(d) = &v.detections[k] {
                observations.push(Observation {
                    camera: Camera::BOTH[k],
                    view: index,
                    corners_px: d.corners_px.clone(),
                    inlier: vec![true; d.corners_px.len()],
                });
            }
        }
    }
    let pairs_used = pair_extrinsics.len();
    let both = cameras.iter().all(Option::is_some);
    let rgb_from_thermal = (both && pairs_used > 0).then(|| average_rigid(&pair_extrinsics));
    if both && pairs_used == 0 {
        warnings.push("no view has the board in both cameras: the thermal↔RGB extrinsic cannot be solved; intrinsics only".into());
    } else if both && pairs_used < 5 {
        warnings.push(format!("only {pairs_used} pairs: the thermal↔RGB extrinsic is weakly constrained (want ≥ 5 pairs at varied poses)"));
    }
    let mut problem = Problem {
        object_points_m: object.clone(),
        cameras,
        rgb_from_thermal,
        poses,
        observations,
    };
    let report = solve(&mut problem, &opts.solve);
    if !report.converged {
        warnings.push(format!(
            "the solver stopped after {} iterations without converging",
            report.iterations.len()
        ));
    }
    if !report.unconstrained.is_empty() {
        warnings.push(format!(
            "parameters the data do not constrain (information ≈ 0): {}",
            report.unconstrained.join(", ")
        ));
    }
    // Per-camera results.
    let res = crate::solve::residuals(&problem);
    let mut out_cameras: [Option<CameraResult>; 2] = [None, None];
    let mut corner_res: [Vec<CornerResidual>; 2] = [Vec::new(), Vec::new()];
    let (mut all_ss, mut all_n) = (0.0, 0usize);
    for camera in Camera::BOTH {
        let k = camera.index();
        let Some(model) = problem.cameras[k] else {
            continue;
        };
        let (mut ss, mut n) = (0.0, 0usize);
        let (mut ss_all, mut n_all) = (0.0, 0usize);
        let mut per_view = Vec::new();
        let mut tilts = Vec::new();
        for (o, r) in problem.observations.iter().zip(&res) {
            if o.camera != camera {
                continue;
            }
            let (vss, vn) = o
                .inlier
                .iter()
                .zip(r)
                .filter(|(i, _)| **i)
                .fold((0.0, 0usize), |(s, n), (_, e)| {
                    (s + e.length_squared(), n + 1)
                });
            ss += vss;
            n += vn;
            ss_all += r.iter().map(|e| e.length_squared()).sum::<f64>();
            n_all += r.len();
            for ((p, e), inl) in o.corners_px.iter().zip(r).zip(&o.inlier) {
                corner_res[k].push(CornerResidual {
                    observed_px: *p,
                    residual_px: *e,
                    inlier: *inl,
                });
            }
            let (frame, pose) = problem.poses[o.view];
            let cam_from_board = match (camera, frame, problem.rgb_from_thermal) {
                (Camera::Rgb, PoseFrame::Thermal, Some(e)) => e.compose(&pose),
                _ => pose,
            };
            let tilt = tilt_deg(&cam_from_board);
            tilts.push(tilt);
            per_view.push(ViewRms {
                key: view_keys[o.view].clone(),
                rms_px: (vss / vn.max(1) as f64).sqrt(),
                corners_used: vn,
                tilt_deg: tilt,
            });
        }
        all_ss += ss;
        all_n += n;
        let max_tilt = tilts.iter().copied().fold(0.0, f64::max);
        if max_tilt < 10.0 {
            warnings.push(format!(
                "{}: all {} views are within {max_tilt:.1}° of fronto-parallel: focal length and principal point are poorly constrained (tilt the board 20–45°)",
                camera.name(),
                tilts.len()
            ));
        }
        coverage_warning(camera, &model, &corner_res[k], &mut warnings);
        let sigma = report.intrinsic_sigma[k].unwrap_or_default();
        let rel = sigma.fx / model.intrinsics.fx;
        if rel.is_nan() || rel >= 0.005 {
            warnings.push(format!(
                "{}: fx uncertainty σ = {:.3} px ({:.2} %) is large",
                camera.name(),
                sigma.fx,
                100.0 * rel
            ));
        }
        out_cameras[k] = Some(CameraResult {
            camera,
            model,
            sigma,
            images: set.images[k],
            views_found: views_found[k],
            views_used: per_view.len(),
            rms_px: (ss / n.max(1) as f64).sqrt(),
            rms_all_px: (ss_all / n_all.max(1) as f64).sqrt(),
            init_rms_px: init_rms[k],
            per_view,
        });
    }
    for camera in Camera::BOTH {
        if set.images[camera.index()] == 0 {
            warnings.push(format!(
                "no {}/ images: calibrating the other camera alone",
                camera.name()
            ));
        }
    }
    Ok(Calibration {
        board: set.board.clone(),
        cameras: out_cameras,
        rgb_from_thermal: problem.rgb_from_thermal,
        extrinsic_sigma: report.extrinsic_sigma,
        joint_rms_px: (all_ss / all_n.max(1) as f64).sqrt(),
        pairs_used,
        warnings,
        problems: set.problems.clone(),
        rejected: report.rejected,
        iterations: report.iterations,
        polarity_note: set.polarity_note.clone(),
        detection_wall_s: set.detection_wall_s,
        solve_wall_s: report.wall_s,
        converged: report.converged,
        residuals: corner_res,
        view_keys,
    })
}

/// Warns when none of the detected corners reach an image corner (outer third in x and y).
fn coverage_warning(
    camera: Camera,
    model: &CameraModel,
    corners: &[CornerResidual],
    warnings: &mut Vec<String>,
) {
    let (w, h) = (f64::from(model.width_px), f64::from(model.height_px));
    let mut hit = [false; 4];
    for c in corners {
        let p = c.observed_px;
        let left = p.x < w / 3.0;
        let right = p.x > 2.0 * w / 3.0;
        let top = p.y < h / 3.0;
        let bottom = p.y > 2.0 * h / 3.0;
        hit[0] |= left && top;
        hit[1] |= right && top;
        hit[2] |= left && bottom;
        hit[3] |= right && bottom;
    }
    let names = ["top-left", "top-right", "bottom-left", "bottom-right"];
    let missing: Vec<&str> = names
        .iter()
        .zip(hit)
        .filter(|(_, h)| !h)
        .map(|(n, _)| *n)
        .collect();
    if !missing.is_empty() {
        warnings.push(format!(
            "{}: no corner was detected in the {} image corner(s): distortion is extrapolated there",
            camera.name(),
            missing.join(", ")
        ));
    }
}

/// Detects and solves a board folder.
pub fn calibrate_folder(dir: &Path, opts: &PipelineOptions) -> Result<Calibration, CalibError> {
    let set = detect_folder(dir, opts.progress)?;
    calibrate_detections(&set, opts)
}

/// Calibrates from a recorded session (`.mcap`) with the board described by `board_toml`.
pub fn calibrate_session(
    session: &Path,
    board_toml: &Path,
    session_opts: &SessionOptions,
    opts: &PipelineOptions,
) -> Result<Calibration, CalibError> {
    let set = detect_session(session, board_toml, session_opts, opts.progress)?;
    calibrate_detections(&set, opts)
}
