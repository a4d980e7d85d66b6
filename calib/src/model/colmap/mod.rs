//! COLMAP sparse models, text (`cameras.txt`, `images.txt`, `points3D.txt`) and binary
//! (`*.bin`), as documented in COLMAP's "Output format" page.
//!
//! The one COLMAP codec of the workspace (OpenCV-free): the trainer reads datasets with it,
//! calib's COLMAP export and the poses stage write through it.
//!
//! Supported camera models: `SIMPLE_PINHOLE` (f, cx, cy), `PINHOLE` (fx, fy, cx, cy),
//! `SIMPLE_RADIAL` (f, cx, cy, k), `RADIAL` (f, cx, cy, k1, k2), `OPENCV`
//! (fx, fy, cx, cy, k1, k2, p1, p2) and `FULL_OPENCV` with k4 = k5 = k6 = 0 (fx, fy, cx, cy,
//! k1, k2, p1, p2, k3, 0, 0, 0). All of them map onto [`CameraModel`] (OpenCV's Brown–Conrady
//! model) exactly. Any other model, or FULL_OPENCV's rational terms, is an error naming it.
//!
//! **Pixel origin**: COLMAP puts the image origin at the top-left *corner* (the centre of the
//! top-left pixel is (0.5, 0.5)); s3tir puts it at the centre (`docs/CONVENTIONS.md`). The readers
//! subtract ½ px from `cx, cy`; the writer ([`write_text_model`]) adds it back.

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use thiserror::Error;

use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::model::geometry::Rigid3;

mod binary;
mod text;

pub use binary::read_binary_model;
pub use text::{cameras_text, read_cameras_text, read_text_model, write_text_model};

/// Errors of reading or writing a COLMAP model. Each names the file (and line, in text files).
#[derive(Debug, Error)]
pub enum ColmapError {
    #[error("{what} not found: {path}")]
    MissingFile { path: PathBuf, what: &'static str },
    #[error("cannot read or write {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {reason}")]
    Parse {
        path: PathBuf,
        line: usize,
        reason: String,
    },
    /// The camera's parameters do not make a valid camera model.
    #[error("{path}")]
    InvalidCamera {
        path: PathBuf,
        #[source]
        source: Box<crate::error::CalibError>,
    },
    #[error(
        "{path}: camera model {model} is not supported (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV with k4 = k5 = k6 = 0)"
    )]
    UnsupportedCameraModel { path: PathBuf, model: String },
    #[error("{path}:{line}: point {point_id} has a NaN or infinite coordinate")]
    NonFinitePoint {
        path: PathBuf,
        line: usize,
        point_id: u64,
    },
}

/// One COLMAP camera (intrinsics in s3tir's pixel convention).
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    /// COLMAP's model name (`PINHOLE`, …).
    pub model_name: String,
    pub model: CameraModel,
}

/// One registered image.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    pub camera_id: u32,
    /// File name relative to the images folder.
    pub name: String,
    pub cam_from_world: Rigid3,
}

/// One sparse point.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub position_m: [f64; 3],
    pub rgb: [u8; 3],
}

/// A whole sparse model.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ColmapModel {
    pub cameras: Vec<ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
}

/// Model ids and names COLMAP assigns (`colmap/sensor/models.h`) with their parameter counts.
const MODELS: &[(i32, &str, usize)] = &[
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

/// Parameter count of a model id (for skipping unsupported models in binary files).
fn param_count(model_id: i32) -> Option<usize> {
    MODELS.iter().find(|m| m.0 == model_id).map(|m| m.2)
}

fn model_name(model_id: i32) -> String {
    MODELS
        .iter()
        .find(|m| m.0 == model_id)
        .map_or_else(|| format!("model id {model_id}"), |m| m.1.to_owned())
}

/// One camera of either reader: the model name and parameter list as COLMAP stores them (text
/// and binary carry the same fields) converted by [`camera_model`]; `line` (0 in binary files)
/// is put into parse errors.
fn colmap_camera(
    file: &Path,
    line: usize,
    id: u32,
    name: &str,
    width: u64,
    height: u64,
    params: &[f64],
) -> Result<ColmapCamera, ColmapError> {
    let model = camera_model(file, name, width, height, params).map_err(|e| match e {
        ColmapError::Parse { path, reason, .. } => ColmapError::Parse { path, line, reason },
        other => other,
    })?;
    Ok(ColmapCamera {
        id,
        model_name: name.to_owned(),
        model,
    })
}

/// Converts COLMAP parameters to a `CameraModel` (½-px shift applied).
fn camera_model(
    file: &Path,
    name: &str,
    width: u64,
    height: u64,
    p: &[f64],
) -> Result<CameraModel, ColmapError> {
    let bad = |reason: String| ColmapError::Parse {
        path: file.to_path_buf(),
        line: 0,
        reason,
    };
    let need = |n: usize| -> Result<(), ColmapError> {
        if p.len() == n {
            Ok(())
        } else {
            Err(bad(format!(
                "camera model {name} needs {n} parameters, got {}",
                p.len()
            )))
        }
    };
    let zero = BrownConrady::default();
    let (fx, fy, cx, cy, dist) = match name {
        "SIMPLE_PINHOLE" => {
            need(3)?;
            (p[0], p[0], p[1], p[2], zero)
        }
        "PINHOLE" => {
            need(4)?;
            (p[0], p[1], p[2], p[3], zero)
        }
        "SIMPLE_RADIAL" => {
            need(4)?;
            let d = BrownConrady { k1: p[3], ..zero };
            (p[0], p[0], p[1], p[2], d)
        }
        "RADIAL" => {
            need(5)?;
            let d = BrownConrady {
                k1: p[3],
                k2: p[4],
                ..zero
            };
            (p[0], p[0], p[1], p[2], d)
        }
        "OPENCV" => {
            need(8)?;
            let d = BrownConrady {
                k1: p[4],
                k2: p[5],
                p1: p[6],
                p2: p[7],
                k3: 0.0,
            };
            (p[0], p[1], p[2], p[3], d)
        }
        "FULL_OPENCV" => {
            need(12)?;
            // fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6: the rational terms k4..k6 divide the radial
            // factor; our 5-parameter Brown–Conrady model is the case k4 = k5 = k6 = 0.
            if p[9..12].iter().any(|&k| k != 0.0) {
                return Err(ColmapError::UnsupportedCameraModel {
                    path: file.to_path_buf(),
                    model: format!(
                        "FULL_OPENCV with rational terms (k4, k5, k6) = ({}, {}, {})",
                        p[9], p[10], p[11]
                    ),
                });
            }
            let d = BrownConrady {
                k1: p[4],
                k2: p[5],
                p1: p[6],
                p2: p[7],
                k3: p[8],
            };
            (p[0], p[1], p[2], p[3], d)
        }
        other => {
            return Err(ColmapError::UnsupportedCameraModel {
                path: file.to_path_buf(),
                model: other.to_owned(),
            });
        }
    };
    let model = CameraModel {
        width_px: u32::try_from(width).map_err(|_| bad(format!("width {width} too large")))?,
        height_px: u32::try_from(height).map_err(|_| bad(format!("height {height} too large")))?,
        intrinsics: Intrinsics {
            fx,
            fy,
            cx: cx - 0.5,
            cy: cy - 0.5,
        },
        distortion: dist,
    };
    model.validate().map_err(|e| ColmapError::InvalidCamera {
        path: file.to_path_buf(),
        source: Box::new(e),
    })?;
    Ok(model)
}

/// Why an image record cannot be used, if it cannot: its name must stay inside the images
/// folder (relative, no `..`: a hostile model must not make the trainer read other files) and
/// its quaternion must have a length to normalise (a zero quaternion became a NaN pose).
fn image_problem(name: &str, q: [f64; 4]) -> Option<String> {
    use std::path::Component;
    if name.is_empty() {
        return Some("image name is empty".into());
    }
    if !Path::new(name)
        .components()
        .all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
    {
        return Some(format!(
            "image name {name:?} leaves the images folder (absolute, or with `..`)"
        ));
    }
    let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm.is_nan() || norm <= 1e-9 {
        return Some(format!(
            "image {name:?}: quaternion {q:?} has no length (a rotation needs |q| > 0)"
        ));
    }
    None
}

fn pose(q: [f64; 4], t: [f64; 3]) -> Rigid3 {
    // COLMAP stores QW QX QY QZ of R_cam_from_world and t_cam_from_world.
    let rot = DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize();
    Rigid3::new(rot, DVec3::from_array(t))
}

/// Where a record stands: its file, and its line in a text file (0 in a binary file, whose
/// errors name the record by its id instead).
#[derive(Debug, Clone, Copy)]
struct At<'a> {
    path: &'a Path,
    line: usize,
}

/// An image record of either reader, checked (a finite pose, a name inside the images folder,
/// a rotation: [`image_problem`]) and built. `v` is `QW QX QY QZ TX TY TZ` as COLMAP stores it.
fn image_record(
    at: At<'_>,
    id: u32,
    camera_id: u32,
    name: String,
    v: [f64; 7],
) -> Result<ColmapImage, ColmapError> {
    let parse = |reason: String| ColmapError::Parse {
        path: at.path.to_path_buf(),
        line: at.line,
        reason: if at.line == 0 {
            format!("image {id}: {reason}")
        } else {
            reason
        },
    };
    if v.iter().any(|x| !x.is_finite()) {
        return Err(parse("pose is not finite".into()));
    }
    if let Some(reason) = image_problem(&name, [v[0], v[1], v[2], v[3]]) {
        return Err(parse(reason));
    }
    Ok(ColmapImage {
        id,
        camera_id,
        name,
        cam_from_world: pose([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]]),
    })
}

/// A sparse point of either reader, checked (finite coordinates) and built.
fn point_record(
    at: At<'_>,
    id: u64,
    position_m: [f64; 3],
    rgb: [u8; 3],
) -> Result<ColmapPoint, ColmapError> {
    if position_m.iter().any(|x| !x.is_finite()) {
        return Err(ColmapError::NonFinitePoint {
            path: at.path.to_path_buf(),
            line: at.line,
            point_id: id,
        });
    }
    Ok(ColmapPoint {
        id,
        position_m,
        rgb,
    })
}

/// The error of opening `path`: a missing file says which file of the model it is.
fn open_error(path: &Path, what: &'static str) -> impl FnOnce(std::io::Error) -> ColmapError {
    let path = path.to_path_buf();
    move |e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            ColmapError::MissingFile { path, what }
        } else {
            ColmapError::Io { path, source: e }
        }
    }
}

/// Reads a model from a folder holding either the text or the binary files (text preferred
/// when both exist).
pub fn read_model(dir: &Path) -> Result<ColmapModel, ColmapError> {
    if dir.join("cameras.txt").exists() {
        read_text_model(dir)
    } else if dir.join("cameras.bin").exists() {
        read_binary_model(dir)
    } else {
        Err(ColmapError::MissingFile {
            path: dir.join("cameras.txt"),
            what: "COLMAP sparse model (cameras.txt or cameras.bin)",
        })
    }
}

/// COLMAP parameter list of a `CameraModel` as `(MODEL, params)` (½-px shift applied): PINHOLE
/// when undistorted, OPENCV when `k3 = 0`, else FULL_OPENCV (with `k4 = k5 = k6 = 0`). The one
/// place s3tir turns a camera into COLMAP's words: the trainer's datasets, calib's COLMAP export
/// and the poses stage all write through it.
pub fn colmap_params(model: &CameraModel) -> (&'static str, Vec<f64>) {
    let i = &model.intrinsics;
    let d = &model.distortion;
    if *d == BrownConrady::default() {
        ("PINHOLE", vec![i.fx, i.fy, i.cx + 0.5, i.cy + 0.5])
    } else if d.k3 == 0.0 {
        (
            "OPENCV",
            vec![i.fx, i.fy, i.cx + 0.5, i.cy + 0.5, d.k1, d.k2, d.p1, d.p2],
        )
    } else {
        (
            "FULL_OPENCV",
            vec![
                i.fx,
                i.fy,
                i.cx + 0.5,
                i.cy + 0.5,
                d.k1,
                d.k2,
                d.p1,
                d.p2,
                d.k3,
                0.0,
                0.0,
                0.0,
            ],
        )
    }
}
