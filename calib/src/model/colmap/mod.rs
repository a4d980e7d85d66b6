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

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use thiserror::Error;

use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::model::geometry::Rigid3;

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

fn read_to_string(path: &Path, what: &'static str) -> Result<String, ColmapError> {
    fs::read_to_string(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            ColmapError::MissingFile {
                path: path.to_path_buf(),
                what,
            }
        } else {
            ColmapError::Io {
                path: path.to_path_buf(),
                source: e,
            }
        }
    })
}

fn parse_f64s(path: &Path, line: usize, toks: &[&str]) -> Result<Vec<f64>, ColmapError> {
    toks.iter()
        .map(|t| {
            t.parse::<f64>().map_err(|_| ColmapError::Parse {
                path: path.to_path_buf(),
                line,
                reason: format!("`{t}` is not a number"),
            })
        })
        .collect()
}

fn parse_int<T: std::str::FromStr>(path: &Path, line: usize, tok: &str) -> Result<T, ColmapError> {
    tok.parse::<T>().map_err(|_| ColmapError::Parse {
        path: path.to_path_buf(),
        line,
        reason: format!("`{tok}` is not an integer"),
    })
}

/// Reads one `cameras.txt` (also the `calibration.colmap-cameras.txt` calib exports).
pub fn read_cameras_text(path: &Path) -> Result<Vec<ColmapCamera>, ColmapError> {
    let text = read_to_string(path, "COLMAP cameras.txt")?;
    let mut cameras = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let toks: Vec<&str> = line.split_whitespace().collect();
        if toks.len() < 4 {
            return Err(ColmapError::Parse {
                path: path.to_path_buf(),
                line: n + 1,
                reason: "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]".into(),
            });
        }
        let id: u32 = parse_int(path, n + 1, toks[0])?;
        let width: u64 = parse_int(path, n + 1, toks[2])?;
        let height: u64 = parse_int(path, n + 1, toks[3])?;
        let params = parse_f64s(path, n + 1, &toks[4..])?;
        cameras.push(colmap_camera(
            path,
            n + 1,
            id,
            toks[1],
            width,
            height,
            &params,
        )?);
    }
    Ok(cameras)
}

/// The `cameras.txt` text of `cameras` (through [`colmap_params`]: ½-px shift applied).
pub fn cameras_text(cameras: &[ColmapCamera]) -> String {
    use std::fmt::Write as _;
    let mut s = String::from("# Camera list: CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    for c in cameras {
        let (name, params) = colmap_params(&c.model);
        let _ = write!(
            s,
            "{} {name} {} {}",
            c.id, c.model.width_px, c.model.height_px
        );
        for p in params {
            let _ = write!(s, " {p:?}");
        }
        s.push('\n');
    }
    s
}

/// Reads `cameras.txt`, `images.txt`, `points3D.txt` (the last may be missing: no points).
pub fn read_text_model(dir: &Path) -> Result<ColmapModel, ColmapError> {
    let mut model = ColmapModel {
        cameras: read_cameras_text(&dir.join("cameras.txt"))?,
        ..ColmapModel::default()
    };

    let path = dir.join("images.txt");
    let text = read_to_string(&path, "COLMAP images.txt")?;
    // Data lines come in pairs: the image line, then its POINTS2D line (possibly empty).
    let mut expect_points_line = false;
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.starts_with('#') {
            continue;
        }
        if expect_points_line {
            expect_points_line = false;
            continue;
        }
        if line.is_empty() {
            continue;
        }
        let toks: Vec<&str> = line.split_whitespace().collect();
        if toks.len() < 10 {
            return Err(ColmapError::Parse {
                path,
                line: n + 1,
                reason: "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME".into(),
            });
        }
        let id: u32 = parse_int(&path, n + 1, toks[0])?;
        let v = parse_f64s(&path, n + 1, &toks[1..8])?;
        let camera_id: u32 = parse_int(&path, n + 1, toks[8])?;
        if v.iter().any(|x| !x.is_finite()) {
            return Err(ColmapError::Parse {
                path,
                line: n + 1,
                reason: "pose is not finite".into(),
            });
        }
        // Names may contain spaces: everything after CAMERA_ID.
        let name = toks[9..].join(" ");
        if let Some(reason) = image_problem(&name, [v[0], v[1], v[2], v[3]]) {
            return Err(ColmapError::Parse {
                path,
                line: n + 1,
                reason,
            });
        }
        model.images.push(ColmapImage {
            id,
            camera_id,
            name,
            cam_from_world: pose([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]]),
        });
        expect_points_line = true;
    }

    let path = dir.join("points3D.txt");
    if path.exists() {
        let text = read_to_string(&path, "COLMAP points3D.txt")?;
        for (n, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let toks: Vec<&str> = line.split_whitespace().collect();
            if toks.len() < 8 {
                return Err(ColmapError::Parse {
                    path,
                    line: n + 1,
                    reason: "expected POINT3D_ID X Y Z R G B ERROR TRACK[]".into(),
                });
            }
            let id: u64 = parse_int(&path, n + 1, toks[0])?;
            let xyz = parse_f64s(&path, n + 1, &toks[1..4])?;
            if xyz.iter().any(|x| !x.is_finite()) {
                return Err(ColmapError::NonFinitePoint {
                    path,
                    line: n + 1,
                    point_id: id,
                });
            }
            let rgb = [
                parse_int(&path, n + 1, toks[4])?,
                parse_int(&path, n + 1, toks[5])?,
                parse_int(&path, n + 1, toks[6])?,
            ];
            model.points.push(ColmapPoint {
                id,
                position_m: [xyz[0], xyz[1], xyz[2]],
                rgb,
            });
        }
    }
    Ok(model)
}

/// Little-endian cursor over a binary COLMAP file.
struct Cursor<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], ColmapError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(ColmapError::Parse {
                path: self.path.to_path_buf(),
                line: 0,
                reason: format!("truncated at byte {} (wanted {n} more)", self.pos),
            });
        };
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self) -> Result<[u8; N], ColmapError> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }
    fn u64(&mut self) -> Result<u64, ColmapError> {
        Ok(u64::from_le_bytes(self.arr()?))
    }
    fn i32(&mut self) -> Result<i32, ColmapError> {
        Ok(i32::from_le_bytes(self.arr()?))
    }
    fn f64(&mut self) -> Result<f64, ColmapError> {
        Ok(f64::from_le_bytes(self.arr()?))
    }
    fn u8(&mut self) -> Result<u8, ColmapError> {
        Ok(self.arr::<1>()?[0])
    }
    fn count(&mut self, elem_bytes: usize) -> Result<usize, ColmapError> {
        let n = self.u64()?;
        // A count that cannot fit in the rest of the file is corruption, not an allocation.
        let remaining = (self.data.len() - self.pos) as u64;
        if n.saturating_mul(elem_bytes as u64) > remaining {
            return Err(ColmapError::Parse {
                path: self.path.to_path_buf(),
                line: 0,
                reason: format!("count {n} at byte {} exceeds the file", self.pos - 8),
            });
        }
        Ok(n as usize)
    }
}

fn read_bytes(path: &Path, what: &'static str) -> Result<Vec<u8>, ColmapError> {
    let mut f = fs::File::open(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            ColmapError::MissingFile {
                path: path.to_path_buf(),
                what,
            }
        } else {
            ColmapError::Io {
                path: path.to_path_buf(),
                source: e,
            }
        }
    })?;
    let mut v = Vec::new();
    f.read_to_end(&mut v).map_err(|e| ColmapError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    Ok(v)
}

/// Reads `cameras.bin`, `images.bin`, `points3D.bin` (the last may be missing).
pub fn read_binary_model(dir: &Path) -> Result<ColmapModel, ColmapError> {
    let mut model = ColmapModel::default();
    let path: PathBuf = dir.join("cameras.bin");
    let data = read_bytes(&path, "COLMAP cameras.bin")?;
    let mut c = Cursor {
        path: &path,
        data: &data,
        pos: 0,
    };
    let n = c.count(24)?;
    for _ in 0..n {
        let id = c.i32()?;
        let model_id = c.i32()?;
        let width = c.u64()?;
        let height = c.u64()?;
        let name = model_name(model_id);
        let Some(np) = param_count(model_id) else {
            return Err(ColmapError::UnsupportedCameraModel {
                path: path.clone(),
                model: name,
            });
        };
        let params = (0..np).map(|_| c.f64()).collect::<Result<Vec<_>, _>>()?;
        model.cameras.push(colmap_camera(
            &path, 0, id as u32, &name, width, height, &params,
        )?);
    }

    let path: PathBuf = dir.join("images.bin");
    let data = read_bytes(&path, "COLMAP images.bin")?;
    let mut c = Cursor {
        path: &path,
        data: &data,
        pos: 0,
    };
    let n = c.count(64)?;
    for _ in 0..n {
        let id = c.i32()?;
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = c.f64()?;
        }
        let camera_id = c.i32()?;
        let mut name = Vec::new();
        loop {
            let b = c.u8()?;
            if b == 0 {
                break;
            }
            name.push(b);
        }
        let np = c.count(24)?;
        c.take(np * 24)?;
        if v.iter().any(|x| !x.is_finite()) {
            return Err(ColmapError::Parse {
                path: path.clone(),
                line: 0,
                reason: format!("image {id}: pose is not finite"),
            });
        }
        let name = String::from_utf8_lossy(&name).into_owned();
        if let Some(reason) = image_problem(&name, [v[0], v[1], v[2], v[3]]) {
            return Err(ColmapError::Parse {
                path: path.clone(),
                line: 0,
                reason: format!("image {id}: {reason}"),
            });
        }
        model.images.push(ColmapImage {
            id: id as u32,
            camera_id: camera_id as u32,
            name,
            cam_from_world: pose([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]]),
        });
    }

    let path: PathBuf = dir.join("points3D.bin");
    if path.exists() {
        let data = read_bytes(&path, "COLMAP points3D.bin")?;
        let mut c = Cursor {
            path: &path,
            data: &data,
            pos: 0,
        };
        let n = c.count(43)?;
        for _ in 0..n {
            let id = c.u64()?;
            let xyz = [c.f64()?, c.f64()?, c.f64()?];
            let rgb = [c.u8()?, c.u8()?, c.u8()?];
            let _error = c.f64()?;
            let track = c.count(8)?;
            c.take(track * 8)?;
            if xyz.iter().any(|x| !x.is_finite()) {
                return Err(ColmapError::NonFinitePoint {
                    path: path.clone(),
                    line: 0,
                    point_id: id,
                });
            }
            model.points.push(ColmapPoint {
                id,
                position_m: xyz,
                rgb,
            });
        }
    }
    Ok(model)
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

/// Writes a text model (for the synthetic scene and tests).
pub fn write_text_model(dir: &Path, model: &ColmapModel) -> Result<(), ColmapError> {
    use std::fmt::Write as _;
    let io = |path: PathBuf| move |e| ColmapError::Io { path, source: e };
    fs::create_dir_all(dir).map_err(io(dir.to_path_buf()))?;
    let s = cameras_text(&model.cameras);
    let p = dir.join("cameras.txt");
    fs::write(&p, s).map_err(io(p.clone()))?;

    let mut s = String::from(
        "# Image list: IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    for im in &model.images {
        let q = im.cam_from_world.rotation;
        let t = im.cam_from_world.translation_m;
        let _ = writeln!(
            s,
            "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {} {}\n",
            im.id, q.w, q.x, q.y, q.z, t.x, t.y, t.z, im.camera_id, im.name
        );
    }
    let p = dir.join("images.txt");
    fs::write(&p, s).map_err(io(p.clone()))?;

    let mut s = String::from("# 3D point list: POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]\n");
    for pt in &model.points {
        let [x, y, z] = pt.position_m;
        let _ = writeln!(
            s,
            "{} {x:?} {y:?} {z:?} {} {} {} 0.0",
            pt.id, pt.rgb[0], pt.rgb[1], pt.rgb[2]
        );
    }
    let p = dir.join("points3D.txt");
    fs::write(&p, s).map_err(io(p.clone()))?;
    Ok(())
}
