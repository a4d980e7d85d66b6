//! COLMAP's text files: `cameras.txt`, `images.txt` (an image line, then its 2-D points line),
//! `points3D.txt`; read with every line's errors named by file and line, and written.

use std::fs;
use std::path::{Path, PathBuf};

use super::{
    At, ColmapCamera, ColmapError, ColmapModel, colmap_camera, colmap_params, image_record,
    open_error, point_record,
};

fn read_to_string(path: &Path, what: &'static str) -> Result<String, ColmapError> {
    fs::read_to_string(path).map_err(open_error(path, what))
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
        let at = At {
            path: &path,
            line: n + 1,
        };
        let id: u32 = parse_int(&path, n + 1, toks[0])?;
        let v = parse_f64s(&path, n + 1, &toks[1..8])?;
        let camera_id: u32 = parse_int(&path, n + 1, toks[8])?;
        // Names may contain spaces: everything after CAMERA_ID.
        let name = toks[9..].join(" ");
        let v = [v[0], v[1], v[2], v[3], v[4], v[5], v[6]];
        model.images.push(image_record(at, id, camera_id, name, v)?);
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
            let at = At {
                path: &path,
                line: n + 1,
            };
            let id: u64 = parse_int(&path, n + 1, toks[0])?;
            let xyz = parse_f64s(&path, n + 1, &toks[1..4])?;
            let rgb = [
                parse_int(&path, n + 1, toks[4])?,
                parse_int(&path, n + 1, toks[5])?,
                parse_int(&path, n + 1, toks[6])?,
            ];
            let point = point_record(at, id, [xyz[0], xyz[1], xyz[2]], rgb)?;
            model.points.push(point);
        }
    }
    Ok(model)
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
