//! Output files: the machine-readable summary, our own `calibration.yaml`, and exports for
//! OpenCV, Kalibr, COLMAP and ROS.
//!
//! ## `calibration.yaml` (format `s3tir-calibration/1`)
//! Plain, diffable YAML written by hand (no YAML library in the workspace):
//! ```yaml
//! format: s3tir-calibration/1
//! pixel_origin: centre-of-top-left-pixel     # OpenCV convention
//! board: {inner_corners: [9, 6], square_mm: 25}
//! cameras:
//!   thermal:                                  # and/or rgb
//!     image_size_px: [160, 120]
//!     model: pinhole+brown-conrady            # OpenCV k1 k2 p1 p2 k3
//!     intrinsics: {fx: .., fy: .., cx: .., cy: ..}
//!     distortion: {k1: .., k2: .., p1: .., p2: .., k3: ..}
//!     sigma: {fx: .., ..., k3: ..}            # 1σ, Gauss–Newton covariance × residual variance
//!     rms_px: ..                              # sqrt(Σ|r|²/N) over inlier corners
//!     views_used: ..
//! rgb_from_thermal:                           # p_rgb = R p_thermal + t (only with pairs)
//!   rotation: [[..], [..], [..]]
//!   quaternion_xyzw: [..]
//!   translation_m: [..]
//!   sigma_rotation_deg: [..]                  # small-angle increments about x, y, z
//!   sigma_translation_m: [..]
//! joint_rms_px: ..
//! pairs_used: ..
//! warnings: [..]
//! ```

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use crate::detect::board::Camera;
use crate::error::CalibError;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::solve::pipeline::{Calibration, CameraResult};

fn rot_rows(t: &Rigid3) -> [[f64; 3]; 3] {
    let m = t.rotation_matrix();
    [
        m.row(0).to_array(),
        m.row(1).to_array(),
        m.row(2).to_array(),
    ]
}

/// The `--summary-json` object.
pub fn summary_json(c: &Calibration) -> Value {
    let mut root = serde_json::Map::new();
    for camera in Camera::BOTH {
        let v = match &c.cameras[camera.index()] {
            Some(r) => json!({
                "images": r.images,
                "views_found": r.views_found,
                "views_partial": r.views_partial,
                "views_used": r.views_used,
                "rms_px": r.rms_px,
                "rms_all_corners_px": r.rms_all_px,
                "mono_rms_px": r.mono_rms_px,
                "mono_rms_all_corners_px": r.mono_rms_all_px,
                "corner_refinement": r.refinement,
                "fx": r.model.intrinsics.fx,
                "fy": r.model.intrinsics.fy,
                "cx": r.model.intrinsics.cx,
                "cy": r.model.intrinsics.cy,
                "distortion": [r.model.distortion.k1, r.model.distortion.k2, r.model.distortion.p1, r.model.distortion.p2, r.model.distortion.k3],
                "image_size_px": [r.model.width_px, r.model.height_px],
                "sigma": r.sigma,
            }),
            None => Value::Null,
        };
        root.insert(camera.name().into(), v);
    }
    root.insert("joint_rms_px".into(), json!(c.joint_rms_px));
    root.insert("pairs_used".into(), json!(c.pairs_used));
    root.insert("pairs_found".into(), json!(c.pairs_found));
    // NaN (a figure a test did not produce) becomes null in JSON.
    root.insert("pairs_inconsistent".into(), json!(c.pairs_inconsistent));
    root.insert("pair_thresholds".into(), json!(c.pair_thresholds));
    root.insert(
        "rgb_from_thermal".into(),
        match c.rgb_from_thermal {
            Some(t) => json!({
                "rotation": rot_rows(&t),
                "translation": t.translation_m.to_array(),
                "translation_units": "m",
                "sigma": c.extrinsic_sigma,
            }),
            None => Value::Null,
        },
    );
    root.insert("warnings".into(), json!(c.warnings));
    root.insert(
        "problems".into(),
        json!(
            c.problems
                .iter()
                .map(|p| json!({"file": p.path, "reason": p.reason}))
                .collect::<Vec<_>>()
        ),
    );
    root.insert("rejected_corners".into(), json!(c.rejected.len()));
    root.insert(
        "solver_iterations".into(),
        json!(c.iterations.len().saturating_sub(1)),
    );
    root.insert("detection_wall_s".into(), json!(c.detection_wall_s));
    root.insert("solve_wall_s".into(), json!(c.solve_wall_s));
    root.insert("thermal_polarity".into(), json!(c.polarity_note));
    Value::Object(root)
}

fn q(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

use crate::model::calfile::yaml_number as f;

fn arr(v: &[f64]) -> String {
    format!(
        "[{}]",
        v.iter().map(|x| f(*x)).collect::<Vec<_>>().join(", ")
    )
}

/// Our own `calibration.yaml` (see module docs).
pub fn calibration_yaml(c: &Calibration) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# s3tir calibration. Pixels: origin at the centre of the top-left pixel (OpenCV)."
    );
    let _ = writeln!(s, "format: s3tir-calibration/1");
    let _ = writeln!(s, "pixel_origin: centre-of-top-left-pixel");
    let _ = writeln!(
        s,
        "board: {{inner_corners: [{}, {}], square_mm: {}}}",
        c.board.cols(),
        c.board.rows(),
        c.board.square_mm
    );
    let _ = writeln!(s, "cameras:");
    for r in c.cameras.iter().flatten() {
        let sg = r.sigma;
        crate::model::calfile::write_camera_block(&mut s, r.camera.name(), &r.model);
        let _ = writeln!(
            s,
            "    sigma: {{fx: {}, fy: {}, cx: {}, cy: {}, k1: {}, k2: {}, p1: {}, p2: {}, k3: {}}}",
            f(sg.fx),
            f(sg.fy),
            f(sg.cx),
            f(sg.cy),
            f(sg.k1),
            f(sg.k2),
            f(sg.p1),
            f(sg.p2),
            f(sg.k3)
        );
        let _ = writeln!(s, "    rms_px: {}", f(r.rms_px));
        let _ = writeln!(s, "    views_used: {}", r.views_used);
    }
    if let Some(t) = c.rgb_from_thermal {
        crate::model::calfile::write_extrinsic_block(&mut s, &t);
        if let Some(sg) = c.extrinsic_sigma {
            let _ = writeln!(s, "  sigma_rotation_deg: {}", arr(&sg.rotation_deg));
            let _ = writeln!(s, "  sigma_translation_m: {}", arr(&sg.translation_m));
        }
    }
    let _ = writeln!(s, "joint_rms_px: {}", f(c.joint_rms_px));
    let _ = writeln!(s, "pairs_used: {}", c.pairs_used);
    let _ = writeln!(
        s,
        "warnings: [{}]",
        c.warnings
            .iter()
            .map(|w| q(w))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s
}

fn opencv_matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    format!(
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        data.iter().map(|v| f(*v)).collect::<Vec<_>>().join(", ")
    )
}

fn k_data(m: &CameraModel) -> [f64; 9] {
    let i = m.intrinsics;
    [i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0]
}

fn d_data(m: &CameraModel) -> [f64; 5] {
    let d = m.distortion;
    [d.k1, d.k2, d.p1, d.p2, d.k3]
}

/// OpenCV FileStorage YAML for one camera (readable by `cv::FileStorage`).
pub fn opencv_yaml(r: &CameraResult) -> String {
    let m = &r.model;
    let mut s = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(s, "image_width: {}", m.width_px);
    let _ = writeln!(s, "image_height: {}", m.height_px);
    s += &opencv_matrix("camera_matrix", 3, 3, &k_data(m));
    s += &opencv_matrix("distortion_coefficients", 1, 5, &d_data(m));
    let _ = writeln!(s, "avg_reprojection_error: {}", f(r.rms_px));
    s
}

/// OpenCV FileStorage YAML of the extrinsic (R, T as `stereoCalibrate` names them: camera 1 =
/// thermal, camera 2 = RGB, p2 = R p1 + T, metres).
pub fn opencv_stereo_yaml(t: &Rigid3) -> String {
    let rows = rot_rows(t);
    let mut s = String::from("%YAML:1.0\n---\n");
    s += &opencv_matrix("R", 3, 3, &rows.concat());
    s += &opencv_matrix("T", 3, 1, &t.translation_m.to_array());
    s
}

/// Kalibr `camchain.yaml`: cam0 = thermal, cam1 = RGB, `T_cn_cnm1` = cam1_from_cam0. Kalibr's
/// `radtan` model has no k3: it is dropped (stated in the file when non-zero).
pub fn kalibr_camchain(c: &Calibration) -> String {
    let mut s = String::from(
        "# Kalibr camchain from s3tir-calib. radtan has no k3; a non-zero k3 is noted per camera.\n",
    );
    for (idx, r) in c.cameras.iter().flatten().enumerate() {
        let m = &r.model;
        let (i, d) = (m.intrinsics, m.distortion);
        let _ = writeln!(s, "cam{idx}:");
        if idx == 1
            && let Some(t) = c.rgb_from_thermal
        {
            let rows = rot_rows(&t);
            let tt = t.translation_m;
            let _ = writeln!(s, "  T_cn_cnm1:");
            for (k, row) in rows.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "  - [{}, {}, {}, {}]",
                    f(row[0]),
                    f(row[1]),
                    f(row[2]),
                    f(tt[k])
                );
            }
            let _ = writeln!(s, "  - [0.0, 0.0, 0.0, 1.0]");
        }
        let _ = writeln!(s, "  camera_model: pinhole");
        let _ = writeln!(
            s,
            "  intrinsics: [{}, {}, {}, {}]",
            f(i.fx),
            f(i.fy),
            f(i.cx),
            f(i.cy)
        );
        let _ = writeln!(s, "  distortion_model: radtan");
        let _ = writeln!(
            s,
            "  distortion_coeffs: [{}, {}, {}, {}]",
            f(d.k1),
            f(d.k2),
            f(d.p1),
            f(d.p2)
        );
        if d.k3 != 0.0 {
            let _ = writeln!(s, "  # k3 = {} dropped (radtan)", f(d.k3));
        }
        let _ = writeln!(s, "  resolution: [{}, {}]", m.width_px, m.height_px);
        let _ = writeln!(s, "  rostopic: /{}/image_raw", r.camera.name());
    }
    s
}

/// COLMAP `cameras.txt` (camera 1 = thermal, 2 = rgb when present), written by the workspace's
/// one COLMAP codec ([`crate::model::colmap::cameras_text`]: PINHOLE, OPENCV or FULL_OPENCV by the
/// distortion, cx, cy shifted by +0.5 to COLMAP's pixel-corner origin), so the trainer's and
/// COLMAP's readers take it.
pub fn colmap_cameras(c: &Calibration) -> String {
    let cameras: Vec<crate::model::colmap::ColmapCamera> = c
        .cameras
        .iter()
        .flatten()
        .map(|r| crate::model::colmap::ColmapCamera {
            id: r.camera.index() as u32 + 1,
            model_name: crate::model::colmap::colmap_params(&r.model).0.to_owned(),
            model: r.model,
        })
        .collect();
    let mut s = String::from("# 1 = thermal, 2 = rgb (when present)\n");
    s.push_str(&crate::model::colmap::cameras_text(&cameras));
    s
}

/// ROS `CameraInfo` YAML (camera_calibration_parsers layout, plumb_bob).
pub fn ros_camera_info(r: &CameraResult) -> String {
    let m = &r.model;
    let i = m.intrinsics;
    let mut s = String::new();
    let _ = writeln!(s, "image_width: {}", m.width_px);
    let _ = writeln!(s, "image_height: {}", m.height_px);
    let _ = writeln!(s, "camera_name: {}", r.camera.name());
    let mat = |name: &str, rows: usize, cols: usize, data: &[f64]| {
        format!(
            "{name}:\n  rows: {rows}\n  cols: {cols}\n  data: {}\n",
            arr(data)
        )
    };
    s += &mat("camera_matrix", 3, 3, &k_data(m));
    let _ = writeln!(s, "distortion_model: plumb_bob");
    s += &mat("distortion_coefficients", 1, 5, &d_data(m));
    s += &mat(
        "rectification_matrix",
        3,
        3,
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    );
    s += &mat(
        "projection_matrix",
        3,
        4,
        &[
            i.fx, 0.0, i.cx, 0.0, 0.0, i.fy, i.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
    );
    s
}

fn write(path: &Path, text: &str) -> Result<PathBuf, CalibError> {
    std::fs::write(path, text).map_err(|e| CalibError::Write {
        path: path.to_path_buf(),
        source: Box::new(e),
    })?;
    Ok(path.to_path_buf())
}

/// Writes `calibration.yaml` at `out` and the exports beside it
/// (`<stem>.opencv-<camera>.yaml`, `<stem>.opencv-stereo.yaml`, `<stem>.camchain.yaml`,
/// `<stem>.colmap-cameras.txt`, `<stem>.ros-<camera>.yaml`). Returns the files written.
pub fn write_all(c: &Calibration, out: &Path) -> Result<Vec<PathBuf>, CalibError> {
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| CalibError::Write {
        path: dir.to_path_buf(),
        source: Box::new(e),
    })?;
    let stem = out
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("calibration");
    let mut written = vec![write(out, &calibration_yaml(c))?];
    for r in c.cameras.iter().flatten() {
        written.push(write(
            &dir.join(format!("{stem}.opencv-{}.yaml", r.camera.name())),
            &opencv_yaml(r),
        )?);
        written.push(write(
            &dir.join(format!("{stem}.ros-{}.yaml", r.camera.name())),
            &ros_camera_info(r),
        )?);
    }
    if let Some(t) = c.rgb_from_thermal {
        written.push(write(
            &dir.join(format!("{stem}.opencv-stereo.yaml")),
            &opencv_stereo_yaml(&t),
        )?);
    }
    written.push(write(
        &dir.join(format!("{stem}.camchain.yaml")),
        &kalibr_camchain(c),
    )?);
    written.push(write(
        &dir.join(format!("{stem}.colmap-cameras.txt")),
        &colmap_cameras(c),
    )?);
    Ok(written)
}

/// Writes the summary JSON.
pub fn write_summary(c: &Calibration, path: &Path) -> Result<(), CalibError> {
    let text = serde_json::to_string_pretty(&summary_json(c)).map_err(|e| CalibError::Write {
        path: path.to_path_buf(),
        source: Box::new(e),
    })?;
    write(path, &text).map(|_| ())
}
