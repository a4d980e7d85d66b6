//! Poses from a folder of images: thermal pictures a user already has — a hand-held FLIR's
//! radiometric JPEGs, a DJI drone's thermal shots with GPS and gimbal angles in their metadata,
//! 16-bit TIFFs in a stated unit — become the same posed COLMAP-layout dataset a recorded
//! session gives (`s3tir-calib poses DIR --out DATASET`, `s3tir-train DIR`).
//!
//! Why here, beside the session stage: it is the same job (images → poses → the trainer's
//! dataset) with another source, and shares its output rules ([`super::output`]: never
//! overwrite, build in `OUT.partial`), the COLMAP codec and the report's place (`poses.json`).
//!
//! ## The stage, in order
//! 1. **Scan** ([`scan`]): which images are thermal and which their RGB partners; every
//!    thermal file read through capture's one reader — radiometric files to kelvin under their
//!    conditions (each overridable), grey images in their stated unit, 8-bit pictures as grey.
//! 2. **Camera** ([`intrinsics`]): calibration file, command line, EXIF, or a known camera;
//!    the report says which.
//! 3. **Priors** ([`geo`]): GPS to local east-north-up metres (origin: the first shot with a
//!    position; up from the barometric relative altitude), gimbal angles to rotations.
//! 4. **Poses**, by the method the scene needs ([`Method`]; `auto` picks in this order):
//!    - the **board** method ([`board`]) with `--board`: PnP on the calibration board in every
//!      shot (a hand-held survey of a heated board);
//!    - the **planar** method ([`plane`]) for a wall or the ground seen by cameras that mostly
//!      translate with known orientation — the case where structure from motion finds no
//!      initial pair: taken when every shot has GPS and gimbal angles and the gimbal's heading
//!      and pitch stay within [`PLANAR_SPREAD_DEG`] of their median (a survey pattern);
//!    - otherwise **structure from motion** ([`sfm`]: COLMAP on the images, or on their RGB
//!      partners with a dual camera's calibration), GPS positions (when the files have them)
//!      carrying the model onto east-north-up metres; without metadata the posing is still
//!      attempted, without priors, and the report says so.
//! 5. **Dataset**: `images/STEM.png` — radiometric shots as 16-bit centikelvin (0.01 K per
//!    count: the trainer's default unit), counts as 16-bit words (train with
//!    `--thermal-units raw`), 8-bit pictures as 8-bit grey; **not undistorted** (the camera in
//!    `sparse/0/cameras.txt` carries the distortion; the trainer undistorts at load, as for
//!    sessions); `sparse/0/` with the posed shots and seed points; `holdout.txt` (every
//!    `holdout_every`-th posed shot by name); `poses.json` ([`FolderReport`]: every shot's
//!    decision and why, the camera's source, the method's figures, the conditions used).
//!    With `--with-rgb` ([`FolderOptions::with_rgb`], [`rgb`]): the posed shots' RGB partners
//!    as `images/rgb_STEM.png` with the calibrated RGB camera as camera 2 — the session
//!    stage's joint layout, for joint RGB + thermal training.

pub mod args;
pub mod board;
pub mod geo;
pub mod intrinsics;
pub mod plane;
pub mod rgb;
pub mod scan;
pub mod sfm;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};
use nalgebra::Matrix3;
use s3tir_capture::radiometric::{ConditionOverrides, Conditions, Units};
use serde::Serialize;

use super::PosesError;
use super::dataset::{RGB_CAMERA_ID, THERMAL_CAMERA_ID};
use super::output::{finish_output, start_output};
use crate::model::camera::CameraModel;
use crate::model::colmap::{
    ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, colmap_params, write_text_model,
};
use crate::model::geometry::Rigid3;
use crate::progress::{Progress, or_silent};
use intrinsics::{IntrinsicsArgs, IntrinsicsSource};
use scan::{Folder, PixelKind, Pixels};

/// `auto` takes the planar method when every shot's gimbal heading and pitch lie within this
/// many degrees of their medians.
pub const PLANAR_SPREAD_DEG: f64 = 10.0;

/// How the shots are posed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Chosen by what the metadata says (module docs).
    Auto,
    /// The planar method ([`plane`]).
    Plane,
    /// PnP on the calibration board in every view ([`board`]; `--board`, with `--calibration`).
    Board,
    /// Structure from motion: COLMAP on the images, or on their RGB partners ([`sfm`]).
    Sfm,
}

/// Options of [`folder_to_dataset`].
#[derive(Debug, Clone, Serialize)]
pub struct FolderOptions {
    pub method: Method,
    /// What 16-bit or float grey images' values are (required for them).
    pub units: Option<Units>,
    /// Overrides of radiometric files' conditions.
    pub conditions: ConditionOverrides,
    #[serde(skip)]
    pub intrinsics: IntrinsicsArgs,
    pub plane: plane::PlaneOptions,
    pub sfm: sfm::SfmOptions,
    /// The calibration board in view (`--board`; its finder is `s3tir-calib`'s OpenCV front
    /// end): `auto` then takes the board method.
    #[serde(skip)]
    pub board: Option<super::board::BoardFiducial>,
    /// Every k-th posed shot (by name) is held out (0: none).
    pub holdout_every: usize,
    /// At most this many seed points (evenly thinned).
    pub max_points: usize,
    /// Also write the posed shots' RGB partners (`--with-rgb`, [`rgb`]).
    pub with_rgb: bool,
    #[serde(skip)]
    pub progress: Option<Arc<dyn Progress>>,
}

impl Default for FolderOptions {
    fn default() -> Self {
        Self {
            method: Method::Auto,
            units: None,
            conditions: ConditionOverrides::default(),
            intrinsics: IntrinsicsArgs::default(),
            plane: plane::PlaneOptions::default(),
            sfm: sfm::SfmOptions::default(),
            board: None,
            holdout_every: 8,
            max_points: 30_000,
            with_rgb: false,
            progress: None,
        }
    }
}

/// Per-shot priors from the metadata ([`geo`]).
#[derive(Debug, Clone)]
pub struct Priors {
    pub tangent: geo::LocalTangent,
    /// East/north metres from the origin.
    pub east_north: Vec<Option<[f64; 2]>>,
    /// Up, metres (relative altitude).
    pub up: Vec<Option<f64>>,
    /// World (ENU) ← camera from the gimbal angles.
    pub world_from_gimbal: Vec<Matrix3<f64>>,
}

/// What a method returns: poses of shots (by index), the shots left out and why, seed points,
/// and the RGB partners' poses where the method measured them itself ([`sfm`] on the
/// partners).
#[derive(Debug, Clone)]
pub struct Posing {
    pub posed: Vec<(usize, Rigid3)>,
    pub left_out: Vec<(usize, String)>,
    pub points: Vec<ColmapPoint>,
    pub rgb_poses: Vec<(usize, Rigid3)>,
}

impl Posing {
    /// A posing of the thermal shots only (the RGB partners, if any, posed afterwards).
    pub fn thermal(
        posed: Vec<(usize, Rigid3)>,
        left_out: Vec<(usize, String)>,
        points: Vec<ColmapPoint>,
    ) -> Self {
        Self {
            posed,
            left_out,
            points,
            rgb_poses: Vec::new(),
        }
    }
}

/// One shot's line in the report.
#[derive(Debug, Clone, Serialize)]
pub struct ShotDecision {
    pub file: String,
    /// The dataset image, when posed.
    pub image: Option<String>,
    pub held_out: bool,
    /// Why it was left out.
    pub left_out: Option<String>,
    pub rgb_partner: Option<String>,
    /// The partner's dataset image (`--with-rgb`), or why it was left out.
    pub rgb_image: Option<String>,
    pub rgb_left_out: Option<String>,
}

/// Seconds per step.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FolderTimes {
    pub scan_s: f64,
    pub pose_s: f64,
    pub write_s: f64,
    pub total_s: f64,
}

/// What the stage did (`poses.json`).
#[derive(Debug, Clone, Serialize)]
pub struct FolderReport {
    pub folder: PathBuf,
    pub dataset: PathBuf,
    pub layout: String,
    pub pixels: PixelKind,
    pub images: usize,
    pub method: Method,
    pub camera: CameraModel,
    pub intrinsics: IntrinsicsSource,
    /// The conditions radiometric files were converted under (the first shot's; each file's
    /// own unless overridden).
    pub conditions: Option<Conditions>,
    pub conditions_overridden: ConditionOverrides,
    /// The local frame's origin (latitude, longitude) when GPS positions were used.
    pub origin_deg: Option<[f64; 2]>,
    pub views: usize,
    pub held_out: usize,
    pub left_out: usize,
    pub seed_points: usize,
    pub plane: Option<plane::PlaneFigures>,
    pub board: Option<board::BoardFigures>,
    pub sfm: Option<sfm::SfmFigures>,
    /// The RGB partners (`--with-rgb`).
    pub rgb: Option<rgb::RgbFigures>,
    pub notes: Vec<String>,
    pub times: FolderTimes,
    pub shots: Vec<ShotDecision>,
}

/// Poses the images of `dir` into a dataset in `out` (module docs).
pub fn folder_to_dataset(
    dir: &Path,
    out: &Path,
    opts: &FolderOptions,
) -> Result<FolderReport, PosesError> {
    let t_all = std::time::Instant::now();
    let progress = or_silent(&opts.progress);
    let mut times = FolderTimes::default();
    let mut notes = Vec::new();
    let folder = scan::scan(dir, opts.units, &opts.conditions, progress)?;
    times.scan_s = t_all.elapsed().as_secs_f64();
    if folder.colour_pictures > 0 {
        notes.push(format!(
            "{} colour thermal picture(s) (palette renders) read by their luma: temperatures are not recoverable from them",
            folder.colour_pictures
        ));
    }
    if folder.kind == PixelKind::Grey8 {
        notes.push("8-bit pictures: no temperatures; values are the camera's per-frame grey (the trainer's per-view response fits the gain)".to_owned());
    }
    let priors = plane::priors(&folder);
    let method = match (opts.method, &priors) {
        (Method::Board | Method::Auto, _) if opts.board.is_some() => Method::Board,
        (Method::Board, _) => {
            return Err(PosesError::Folder {
                path: dir.to_path_buf(),
                reason: "--method board needs the board: --board board.toml".to_owned(),
            });
        }
        (Method::Plane, Err(why)) => {
            return Err(PosesError::Folder {
                path: dir.to_path_buf(),
                reason: format!("the planar method needs GPS positions and gimbal angles: {why}"),
            });
        }
        (Method::Plane, Ok(_)) => Method::Plane,
        (Method::Auto, Ok(_)) if survey_pattern(&folder) => Method::Plane,
        (Method::Auto, Ok(_)) => {
            notes.push(format!(
                "the gimbal's heading or pitch varies by more than {PLANAR_SPREAD_DEG}° between shots (not a survey of one plane): posed by structure from motion, GPS positions as the world"
            ));
            Method::Sfm
        }
        (Method::Auto, Err(why)) => {
            notes.push(format!(
                "no usable GPS/gimbal metadata ({why}): posed by structure from motion without priors"
            ));
            Method::Sfm
        }
        (Method::Sfm, _) => Method::Sfm,
    };
    let (camera, intrinsics) = intrinsics::thermal_camera(&folder, &opts.intrinsics)?;
    if method == Method::Board && !matches!(intrinsics, IntrinsicsSource::Calibration { .. }) {
        return Err(PosesError::MissingCalibration {
            what: "thermal camera for the board method",
            why: "no --calibration given (the board's corners are undistorted with it; calibrate the folder first: s3tir-calib DIR --out calibration.yaml with DIR/board.toml)".to_owned(),
        });
    }
    let rgb_rig = if opts.with_rgb {
        Some(rgb::rgb_rig(&folder, &opts.intrinsics, method)?)
    } else {
        None
    };
    // Structure from motion runs on the RGB partners when the calibration has their camera
    // and the extrinsic ([`sfm`]), whether or not they are written.
    let sfm_rig = match (&rgb_rig, method) {
        (Some(r), Method::Sfm) => Some(*r),
        (None, Method::Sfm) if folder.shots.iter().all(|s| s.rgb.is_some()) => {
            match rgb::rgb_rig(&folder, &opts.intrinsics, method) {
                Ok(r) => Some(r),
                Err(e) => {
                    notes.push(format!(
                        "structure from motion on the thermal images, not the RGB partners: {}",
                        s3tir_capture::Chain(&e)
                    ));
                    None
                }
            }
        }
        _ => None,
    };
    if method == Method::Sfm {
        super::sfm::check_colmap(&opts.sfm.colmap)?;
    }
    // Only now (inputs checked) is anything created.
    let partial = start_output(out)?;
    let t = std::time::Instant::now();
    let (mut plane_figures, mut board_figures, mut sfm_figures) = (None, None, None);
    let posing = match method {
        Method::Board => {
            let b = opts.board.as_ref().ok_or_else(|| PosesError::Folder {
                path: dir.to_path_buf(),
                reason: "--method board needs the board: --board board.toml".to_owned(),
            })?;
            let (posing, fig) = board::pose(&folder, &camera, b, progress)?;
            board_figures = Some(fig);
            posing
        }
        Method::Sfm => {
            let workspace = partial.join("colmap");
            let (posing, fig) = sfm::pose(
                &folder,
                &camera,
                sfm_rig.as_ref(),
                &opts.sfm,
                &workspace,
                progress,
            )?;
            notes.extend(gps_note(&fig.gps_disagrees));
            if fig.world == "colmap" {
                notes.push("no GPS positions and no --metres-per-unit: the world is COLMAP's, of arbitrary scale (the lever arm to the RGB partners, if any, left out)".to_owned());
            }
            sfm_figures = Some(fig);
            posing
        }
        Method::Plane | Method::Auto => {
            let p = priors.as_ref().map_err(|why| PosesError::Folder {
                path: dir.to_path_buf(),
                reason: why.clone(),
            })?;
            let (posing, fig) = plane::pose(&folder, &camera, p, &opts.plane, progress)?;
            notes.extend(gps_note(&fig.gps_disagrees));
            plane_figures = Some(fig);
            posing
        }
    };
    let rgb = match &rgb_rig {
        Some(r) => {
            let board = opts.board.as_ref().filter(|_| method == Method::Board);
            // In COLMAP's unscaled world the lever arm has no length: the extrinsic's
            // rotation only (as the thermal poses were composed, [`sfm`]).
            let unscaled = sfm_figures.as_ref().is_some_and(|f| f.world == "colmap");
            let composed = rgb::RgbRig {
                rgb_from_thermal: r.rgb_from_thermal.map(|e| {
                    if unscaled {
                        Rigid3::new(e.rotation, DVec3::ZERO)
                    } else {
                        e
                    }
                }),
                ..*r
            };
            let mut posed = rgb::pose_rgb(&folder, &posing, &composed, board, progress)?;
            posed.figures.lever_arm_m = r.rgb_from_thermal.map(|e| e.translation_m.length());
            Some(RgbOut {
                rig: *r,
                posing: posed,
            })
        }
        None => None,
    };
    times.pose_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let (shots, points, rgb) = write_dataset(&partial, &folder, &camera, &posing, rgb, opts)?;
    times.write_s = t.elapsed().as_secs_f64();
    times.total_s = t_all.elapsed().as_secs_f64();
    let report = FolderReport {
        folder: dir.to_path_buf(),
        dataset: out.to_path_buf(),
        layout: folder.layout.clone(),
        pixels: folder.kind,
        images: folder.shots.len(),
        method,
        camera,
        intrinsics,
        conditions: folder.shots[0].conditions,
        conditions_overridden: opts.conditions,
        origin_deg: priors.as_ref().ok().map(|p| {
            [
                p.tangent.origin().latitude_deg,
                p.tangent.origin().longitude_deg,
            ]
        }),
        views: shots
            .iter()
            .filter(|s| s.image.is_some() && !s.held_out)
            .count(),
        held_out: shots.iter().filter(|s| s.held_out).count(),
        left_out: shots.iter().filter(|s| s.left_out.is_some()).count(),
        seed_points: points,
        plane: plane_figures,
        board: board_figures,
        sfm: sfm_figures,
        rgb,
        notes,
        times,
        shots,
    };
    let p = partial.join("poses.json");
    let text = serde_json::to_string_pretty(&report).map_err(|e| write_err(&p, e))?;
    std::fs::write(&p, text).map_err(|e| write_err(&p, e))?;
    finish_output(&partial, out)?;
    Ok(report)
}

/// The report's note on shots whose GPS fix disagrees with the images beyond 3 σ (file,
/// metres), if any.
fn gps_note(disagrees: &[(String, f64)]) -> Option<String> {
    let names: Vec<String> = disagrees
        .iter()
        .map(|(n, d)| format!("{n} ({d:.1} m)"))
        .collect();
    (!names.is_empty()).then(|| {
        format!(
            "GPS disagrees with the images beyond 3 σ for {}: their positions come from the images",
            names.join(", ")
        )
    })
}

/// Whether the shots are a survey of one plane (module docs).
fn survey_pattern(folder: &Folder) -> bool {
    let g: Vec<_> = folder.shots.iter().filter_map(|s| s.meta.gimbal).collect();
    if g.len() != folder.shots.len() || g.is_empty() {
        return false;
    }
    let mut pitch: Vec<f64> = g.iter().map(|a| a.pitch_deg).collect();
    pitch.sort_by(f64::total_cmp);
    let mp = pitch[pitch.len() / 2];
    let mut yaw: Vec<f64> = g.iter().map(|a| a.yaw_deg).collect();
    yaw.sort_by(f64::total_cmp);
    let my = yaw[yaw.len() / 2];
    let dyaw = |y: f64| {
        let d = (y - my).rem_euclid(360.0);
        d.min(360.0 - d)
    };
    // Nadir shots' heading does not change what they see of the ground by more than a turn of
    // the image; only the pitch matters there.
    let nadir = mp < -80.0;
    g.iter().all(|a| {
        (a.pitch_deg - mp).abs() <= PLANAR_SPREAD_DEG
            && (nadir || dyaw(a.yaw_deg) <= PLANAR_SPREAD_DEG)
    })
}

fn write_err(path: &Path, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> PosesError {
    PosesError::Write {
        path: path.to_path_buf(),
        source: e.into(),
    }
}

/// The posed RGB partners, for [`write_dataset`].
struct RgbOut {
    rig: rgb::RgbRig,
    posing: rgb::RgbPosing,
}

/// Writes images, the COLMAP model and `holdout.txt`; returns every shot's decision, the
/// number of seed points written and the RGB figures.
fn write_dataset(
    out: &Path,
    folder: &Folder,
    camera: &CameraModel,
    posing: &Posing,
    rgb: Option<RgbOut>,
    opts: &FolderOptions,
) -> Result<(Vec<ShotDecision>, usize, Option<rgb::RgbFigures>), PosesError> {
    let images = out.join("images");
    std::fs::create_dir_all(&images).map_err(|e| write_err(&images, e))?;
    let mut posed = posing.posed.clone();
    posed.sort_by(|a, b| folder.shots[a.0].name.cmp(&folder.shots[b.0].name));
    let image_name = |i: usize| {
        let s = &folder.shots[i];
        let stem = s
            .path
            .file_stem()
            .map(|x| x.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("shot_{i:04}"));
        format!("{stem}.png")
    };
    let mut decisions: Vec<ShotDecision> = folder
        .shots
        .iter()
        .map(|s| ShotDecision {
            file: s.name.clone(),
            image: None,
            held_out: false,
            left_out: None,
            rgb_partner: s
                .rgb
                .as_ref()
                .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned())),
            rgb_image: None,
            rgb_left_out: None,
        })
        .collect();
    for (i, why) in &posing.left_out {
        decisions[*i].left_out = Some(why.clone());
    }
    let mut holdout = String::new();
    let mut model_images = Vec::new();
    let progress = or_silent(&opts.progress);
    progress.start("writing the dataset", Some(posed.len() as u64));
    for (k, (i, world_from_cam)) in posed.iter().enumerate() {
        let s = &folder.shots[*i];
        let name = image_name(*i);
        let p = images.join(&name);
        let (w, h) = (s.width as u32, s.height as u32);
        let saved = match &s.pixels {
            Pixels::Words(words) => {
                image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, words.clone())
                    .map(|img| img.save(&p))
            }
            Pixels::Grey8(g) => image::ImageBuffer::<image::Luma<u8>, _>::from_raw(w, h, g.clone())
                .map(|img| img.save(&p)),
        };
        match saved {
            Some(r) => r.map_err(|e| write_err(&p, e))?,
            None => return Err(write_err(&p, "pixel count does not match the size")),
        }
        let held = opts.holdout_every > 0 && k % opts.holdout_every == 0;
        if held {
            holdout.push_str(&name);
            holdout.push('\n');
        }
        decisions[*i].image = Some(name.clone());
        decisions[*i].held_out = held;
        model_images.push(ColmapImage {
            id: k as u32 + 1,
            camera_id: THERMAL_CAMERA_ID,
            name,
            cam_from_world: world_from_cam.inverse(),
        });
        progress.advance(1);
    }
    progress.finish();
    let mut cameras = vec![ColmapCamera {
        id: THERMAL_CAMERA_ID,
        model_name: colmap_params(camera).0.to_owned(),
        model: *camera,
    }];
    let rgb_figures = match rgb {
        None => None,
        Some(r) => {
            cameras.push(ColmapCamera {
                id: RGB_CAMERA_ID,
                model_name: colmap_params(&r.rig.camera).0.to_owned(),
                model: r.rig.camera,
            });
            for (i, why) in &r.posing.left_out {
                decisions[*i].rgb_left_out = Some(why.clone());
            }
            let mut figures = r.posing.figures;
            progress.start(
                "writing the RGB partners",
                Some(r.posing.views.len() as u64),
            );
            for v in &r.posing.views {
                let Some(src) = folder.shots[v.shot].rgb.as_ref() else {
                    continue;
                };
                let name = format!("rgb_{}", image_name(v.shot));
                rgb::write_partner(src, &images.join(&name))?;
                let held = decisions[v.shot].held_out;
                if held {
                    holdout.push_str(&name);
                    holdout.push('\n');
                    figures.held_out += 1;
                }
                figures.views += 1;
                decisions[v.shot].rgb_image = Some(name.clone());
                model_images.push(ColmapImage {
                    id: model_images.len() as u32 + 1,
                    camera_id: RGB_CAMERA_ID,
                    name,
                    cam_from_world: v.world_from_rgb.inverse(),
                });
                progress.advance(1);
            }
            progress.finish();
            Some(figures)
        }
    };
    let points = thin(&posing.points, opts.max_points);
    let model = ColmapModel {
        cameras,
        images: model_images,
        points: points.clone(),
    };
    let sparse = out.join("sparse").join("0");
    write_text_model(&sparse, &model).map_err(|e| write_err(&sparse, e))?;
    let p = out.join("holdout.txt");
    std::fs::write(&p, holdout).map_err(|e| write_err(&p, e))?;
    Ok((decisions, points.len(), rgb_figures))
}

/// Seed points of a planar scene: the plane `normal · x = distance` (world) seen through each
/// posed view at every 8th pixel (the camera's distortion undone), each with the view's grey
/// value there (0–255 over the folder's range, [`Folder::grey_for_matching`]).
fn plane_seeds(
    folder: &Folder,
    cam: &CameraModel,
    posed: &[(usize, Rigid3)],
    normal: DVec3,
    distance: f64,
) -> Vec<ColmapPoint> {
    let grey = folder.grey_for_matching();
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    let mut points = Vec::new();
    for (i, world_from_cam) in posed {
        let c = world_from_cam.translation_m;
        for y in (4..h).step_by(8) {
            for x in (4..w).step_by(8) {
                let Some(ray) = cam.unproject(DVec2::new(x as f64, y as f64)) else {
                    continue;
                };
                let d = world_from_cam.transform_vector(ray);
                let denom = normal.dot(d);
                if denom.abs() < 1e-9 {
                    continue;
                }
                let s = (distance - normal.dot(c)) / denom;
                if s <= 0.0 {
                    continue;
                }
                let p = c + d * s;
                let g = grey[*i][y * w + x].round().clamp(0.0, 255.0) as u8;
                points.push(ColmapPoint {
                    id: points.len() as u64 + 1,
                    position_m: p.to_array(),
                    rgb: [g, g, g],
                });
            }
        }
    }
    points
}

/// At most `max` of `points`, evenly spread over the list (deterministic), renumbered.
fn thin(points: &[ColmapPoint], max: usize) -> Vec<ColmapPoint> {
    if points.len() <= max {
        return points.to_vec();
    }
    (0..max)
        .map(|k| {
            let mut p = points[k * points.len() / max].clone();
            p.id = k as u64 + 1;
            p
        })
        .collect()
}

/// The lines the CLI prints.
pub fn summary(r: &FolderReport) -> String {
    let mut s = format!(
        "{}: {} thermal images ({}, {:?}); camera from {}\n",
        r.folder.display(),
        r.images,
        r.layout,
        r.pixels,
        match &r.intrinsics {
            IntrinsicsSource::Calibration { path } => format!("the calibration {}", path.display()),
            IntrinsicsSource::CommandLine => "the command line".to_owned(),
            IntrinsicsSource::Exif35mm { focal_35mm } =>
                format!("EXIF (35 mm-equivalent focal length {focal_35mm} mm)"),
            IntrinsicsSource::KnownCamera { camera, .. } => format!("the known camera {camera}"),
        }
    );
    if let Some(p) = &r.plane {
        s += &format!(
            "planar method: {} of {} candidate pairs registered, {} agree; scale {} px/m; {} points in {} observations\n\
             reprojection error median {:.2} px, 90th percentile {:.2} px; plane {:.2} m away, {:.1}° off the mean heading; cameras moved {:.2} m from GPS (median), turned {:.2}° from the gimbal angles\n",
            p.pairs_registered,
            p.candidate_pairs,
            p.pairs_agreeing,
            p.scale_px_per_m
                .iter()
                .map(|x| format!("{x:.1}"))
                .collect::<Vec<_>>()
                .join(" → "),
            p.points,
            p.observations,
            p.reprojection_px_median,
            p.reprojection_px_p90,
            p.plane_distance_m,
            p.plane_tilt_deg,
            p.moved_from_gps_m_median,
            p.turned_from_gimbal_deg_median,
        );
    }
    if let Some(b) = &r.board {
        s += &format!(
            "board method: found in {} images, {} posed by PnP (RMS median {:.2} px, max {:.2} px), cameras {:.2}–{:.2} m above the board\n",
            b.board_found,
            b.posed,
            b.pnp_rms_px_median,
            b.pnp_rms_px_max,
            b.height_m[0],
            b.height_m[1]
        );
    }
    if let Some(f) = &r.sfm {
        s += &format!(
            "structure from motion (COLMAP) on the {}: {} of {} registered, {} points; world: {}{}\n",
            if f.images_of == "rgb_partners" {
                "RGB partners"
            } else {
                "thermal images"
            },
            f.registered,
            f.images,
            f.points,
            match f.world.as_str() {
                "east_north_up" => "east-north-up metres from the GPS positions".to_owned(),
                "scaled" => "COLMAP's, scaled by --metres-per-unit".to_owned(),
                _ => "COLMAP's (arbitrary scale)".to_owned(),
            },
            f.gps_residual_m_median
                .map(|m| format!(" (cameras {m:.2} m from their GPS positions, median)"))
                .unwrap_or_default()
        );
    }
    if let Some(g) = &r.rgb {
        s += &format!(
            "RGB partners: {} views written ({} held out) of {} posed shots with a partner; {} posed by structure from motion, {} by PnP on the board{}, {} by the calibrated extrinsic{}\n",
            g.views,
            g.held_out,
            g.partners,
            g.from_sfm,
            g.from_board,
            g.pnp_rms_px_median
                .map(|m| format!(" (RMS median {m:.2} px)"))
                .unwrap_or_default(),
            g.from_extrinsic,
            match (g.centre_gap_m, g.lever_arm_m) {
                (Some([m, x]), Some(l)) => format!(
                    "; thermal and RGB centres {m:.3} m apart (median, largest {x:.3} m; the calibrated lever arm is {l:.3} m)"
                ),
                (Some([m, x]), None) =>
                    format!("; thermal and RGB centres {m:.3} m apart (median, largest {x:.3} m)"),
                _ => String::new(),
            }
        );
    }
    let left: Vec<String> = r
        .shots
        .iter()
        .filter_map(|d| d.left_out.as_ref().map(|w| format!("{} ({w})", d.file)))
        .collect();
    s += &format!(
        "{} of {} views posed ({} held out), {} seed points; written to {}\n",
        r.views + r.held_out,
        r.images,
        r.held_out,
        r.seed_points,
        r.dataset.display()
    );
    if !left.is_empty() {
        s += &format!("left out: {}\n", left.join(", "));
    }
    let rgb_left: Vec<String> = r
        .shots
        .iter()
        .filter_map(|d| d.rgb_left_out.as_ref().map(|w| format!("{} ({w})", d.file)))
        .collect();
    if !rgb_left.is_empty() {
        s += &format!("RGB partners left out: {}\n", rgb_left.join(", "));
    }
    for n in &r.notes {
        s += &format!("note: {n}\n");
    }
    s += &format!(
        "took {:.1} s (reading {:.1} s, posing {:.1} s, writing {:.1} s)\n",
        r.times.total_s, r.times.scan_s, r.times.pose_s, r.times.write_s
    );
    s
}
