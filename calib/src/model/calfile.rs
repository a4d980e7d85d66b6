//! `calibration.yaml` (format `s3tir-calibration/1`) as the other stages read it: the camera
//! models and the thermal↔RGB extrinsic, without OpenCV. calib's pipeline writes the full file
//! (`export::calibration_yaml`, with sigmas, RMS and warnings); this module reads any such file
//! back ([`CalibrationFile::read`]) and writes the model-only subset ([`CalibrationFile::to_yaml`])
//! for ground truth and tests. The layout is documented in `export.rs`'s module docs.
//!
//! What is read: `format` (must be `s3tir-calibration/1`), `cameras.thermal` /
//! `cameras.rgb` (`image_size_px`, `intrinsics`, `distortion`), `rgb_from_thermal`
//! (`rotation` rows, else `quaternion_xyzw`; `translation_m`). Everything else is kept out of
//! the way: a newer writer may add keys.

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use thiserror::Error;
use yaml_rust2::{Yaml, YamlLoader};

use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::model::geometry::Rigid3;

/// The format line every calibration file carries.
pub const FORMAT: &str = "s3tir-calibration/1";

/// Errors of reading a calibration file; each names the file and, where it applies, the key.
#[derive(Debug, Error)]
pub enum CalFileError {
    #[error("calibration file {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("calibration file {path} is not YAML")]
    Syntax {
        path: PathBuf,
        #[source]
        source: yaml_rust2::ScanError,
    },
    /// YAML that holds no document.
    #[error("calibration file {path} is not YAML: the file is empty")]
    Empty { path: PathBuf },
    #[error(
        "calibration file {path}: format is {found:?}, expected \"{FORMAT}\" (written by s3tir-calib --out calibration.yaml)"
    )]
    Format { path: PathBuf, found: String },
    #[error("calibration file {path}: key {key}: {reason}")]
    Key {
        path: PathBuf,
        key: String,
        reason: String,
    },
    #[error("calibration file {path}: camera {camera} is not a valid model")]
    Model {
        path: PathBuf,
        camera: &'static str,
        #[source]
        source: Box<crate::error::CalibError>,
    },
}

/// The parts of a calibration the other stages use.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationFile {
    pub thermal: Option<CameraModel>,
    pub rgb: Option<CameraModel>,
    /// Maps thermal-camera points into the RGB camera frame (present when pairs were solved).
    pub rgb_from_thermal: Option<Rigid3>,
}

fn key_err(path: &Path, key: &str, reason: impl Into<String>) -> CalFileError {
    CalFileError::Key {
        path: path.to_path_buf(),
        key: key.to_owned(),
        reason: reason.into(),
    }
}

fn number(path: &Path, key: &str, y: &Yaml) -> Result<f64, CalFileError> {
    match y {
        Yaml::Real(_) => y.as_f64().ok_or_else(|| key_err(path, key, "not a number")),
        Yaml::Integer(i) => Ok(*i as f64),
        Yaml::BadValue => Err(key_err(path, key, "missing")),
        other => Err(key_err(path, key, format!("not a number: {other:?}"))),
    }
    .and_then(|v| {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(key_err(path, key, format!("{v} is not finite")))
        }
    })
}

fn numbers<const N: usize>(path: &Path, key: &str, y: &Yaml) -> Result<[f64; N], CalFileError> {
    let v = y
        .as_vec()
        .ok_or_else(|| key_err(path, key, format!("expected a list of {N} numbers")))?;
    if v.len() != N {
        return Err(key_err(
            path,
            key,
            format!("expected {N} numbers, found {}", v.len()),
        ));
    }
    let mut out = [0.0; N];
    for (k, e) in v.iter().enumerate() {
        out[k] = number(path, &format!("{key}[{k}]"), e)?;
    }
    Ok(out)
}

fn camera(path: &Path, name: &'static str, y: &Yaml) -> Result<CameraModel, CalFileError> {
    let key = |k: &str| format!("cameras.{name}.{k}");
    let [w, h] = numbers::<2>(path, &key("image_size_px"), &y["image_size_px"])?;
    let i = &y["intrinsics"];
    let d = &y["distortion"];
    let num = |y: &Yaml, k: &str| number(path, &key(k), y);
    let model = CameraModel {
        width_px: w as u32,
        height_px: h as u32,
        intrinsics: Intrinsics {
            fx: num(&i["fx"], "intrinsics.fx")?,
            fy: num(&i["fy"], "intrinsics.fy")?,
            cx: num(&i["cx"], "intrinsics.cx")?,
            cy: num(&i["cy"], "intrinsics.cy")?,
        },
        distortion: BrownConrady {
            k1: num(&d["k1"], "distortion.k1")?,
            k2: num(&d["k2"], "distortion.k2")?,
            p1: num(&d["p1"], "distortion.p1")?,
            p2: num(&d["p2"], "distortion.p2")?,
            k3: num(&d["k3"], "distortion.k3")?,
        },
    };
    if w < 1.0 || h < 1.0 || w.fract() != 0.0 || h.fract() != 0.0 {
        return Err(key_err(
            path,
            &key("image_size_px"),
            format!("{w}×{h} is not an image size"),
        ));
    }
    model.validate().map_err(|e| CalFileError::Model {
        path: path.to_path_buf(),
        camera: name,
        source: Box::new(e),
    })?;
    Ok(model)
}

/// Formats a number as every calibration file writes it (10 significant digits, `.nan`).
pub fn yaml_number(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.10e}")
    } else {
        ".nan".into()
    }
}

/// Writes a camera's block under `cameras:` (`  NAME:`, size, model, intrinsics, distortion):
/// the lines [`CalibrationFile::read`] reads. calib's full writer appends its sigmas and RMS.
pub fn write_camera_block(s: &mut String, name: &str, m: &CameraModel) {
    use std::fmt::Write as _;
    let f = yaml_number;
    let (i, d) = (m.intrinsics, m.distortion);
    let _ = writeln!(s, "  {name}:");
    let _ = writeln!(s, "    image_size_px: [{}, {}]", m.width_px, m.height_px);
    let _ = writeln!(s, "    model: pinhole+brown-conrady");
    let _ = writeln!(
        s,
        "    intrinsics: {{fx: {}, fy: {}, cx: {}, cy: {}}}",
        f(i.fx),
        f(i.fy),
        f(i.cx),
        f(i.cy)
    );
    let _ = writeln!(
        s,
        "    distortion: {{k1: {}, k2: {}, p1: {}, p2: {}, k3: {}}}",
        f(d.k1),
        f(d.k2),
        f(d.p1),
        f(d.p2),
        f(d.k3)
    );
}

/// Writes the `rgb_from_thermal:` block's rotation, quaternion and translation lines.
pub fn write_extrinsic_block(s: &mut String, t: &Rigid3) {
    use std::fmt::Write as _;
    let f = yaml_number;
    let list = |v: &[f64]| {
        format!(
            "[{}]",
            v.iter().map(|x| f(*x)).collect::<Vec<_>>().join(", ")
        )
    };
    let m = t.rotation_matrix();
    let row = |r: usize| list(&m.row(r).to_array());
    let _ = writeln!(s, "rgb_from_thermal:");
    let _ = writeln!(s, "  rotation: [{}, {}, {}]", row(0), row(1), row(2));
    let _ = writeln!(s, "  quaternion_xyzw: {}", list(&t.rotation.to_array()));
    let _ = writeln!(s, "  translation_m: {}", list(&t.translation_m.to_array()));
}

impl CalibrationFile {
    /// Reads `path` (see module docs for what is read).
    pub fn read(path: &Path) -> Result<Self, CalFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| CalFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(path, &text)
    }

    /// Parses the text of a calibration file; `path` only names it in errors.
    pub fn parse(path: &Path, text: &str) -> Result<Self, CalFileError> {
        let docs = YamlLoader::load_from_str(text).map_err(|source| CalFileError::Syntax {
            path: path.to_path_buf(),
            source,
        })?;
        let Some(root) = docs.first() else {
            return Err(CalFileError::Empty {
                path: path.to_path_buf(),
            });
        };
        let format = root["format"].as_str().unwrap_or_default();
        if format != FORMAT {
            return Err(CalFileError::Format {
                path: path.to_path_buf(),
                found: format.to_owned(),
            });
        }
        let cams = &root["cameras"];
        let thermal = match &cams["thermal"] {
            Yaml::BadValue | Yaml::Null => None,
            y => Some(camera(path, "thermal", y)?),
        };
        let rgb = match &cams["rgb"] {
            Yaml::BadValue | Yaml::Null => None,
            y => Some(camera(path, "rgb", y)?),
        };
        let rgb_from_thermal = match &root["rgb_from_thermal"] {
            Yaml::BadValue | Yaml::Null => None,
            e => {
                let t = numbers::<3>(path, "rgb_from_thermal.translation_m", &e["translation_m"])?;
                let rotation = match &e["rotation"] {
                    Yaml::Array(rows) if rows.len() == 3 => {
                        let mut m = [[0.0; 3]; 3];
                        for (r, row) in rows.iter().enumerate() {
                            m[r] = numbers::<3>(
                                path,
                                &format!("rgb_from_thermal.rotation[{r}]"),
                                row,
                            )?;
                        }
                        let mat = DMat3::from_cols_array_2d(&m).transpose();
                        // A rotation matrix written to 10 digits: orthonormal to ~1e-10.
                        let orth = (mat.transpose() * mat - DMat3::IDENTITY)
                            .to_cols_array()
                            .iter()
                            .fold(0.0f64, |a, v| a.max(v.abs()));
                        if orth > 1e-6 || (mat.determinant() - 1.0).abs() > 1e-6 {
                            return Err(key_err(
                                path,
                                "rgb_from_thermal.rotation",
                                format!(
                                    "not a rotation (|RᵀR − I| = {orth:.1e}, det = {:.6})",
                                    mat.determinant()
                                ),
                            ));
                        }
                        DQuat::from_mat3(&mat).normalize()
                    }
                    _ => {
                        let q = numbers::<4>(
                            path,
                            "rgb_from_thermal.quaternion_xyzw",
                            &e["quaternion_xyzw"],
                        )?;
                        let quat = DQuat::from_array(q);
                        if (quat.length() - 1.0).abs() > 1e-6 {
                            return Err(key_err(
                                path,
                                "rgb_from_thermal.quaternion_xyzw",
                                format!("not a unit quaternion (norm {})", quat.length()),
                            ));
                        }
                        quat.normalize()
                    }
                };
                Some(Rigid3::new(rotation, DVec3::from_array(t)))
            }
        };
        Ok(Self {
            thermal,
            rgb,
            rgb_from_thermal,
        })
    }

    /// The model-only subset of the file (no sigmas, RMS or warnings), in the layout
    /// `s3tir-calib` writes, so [`CalibrationFile::read`] and every reader of the full file
    /// read it. For ground truth (the simulated rig) and tests.
    pub fn to_yaml(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::from(
            "# s3tir calibration (models only). Pixels: origin at the centre of the top-left pixel (OpenCV).\n",
        );
        let _ = writeln!(s, "format: {FORMAT}");
        let _ = writeln!(s, "pixel_origin: centre-of-top-left-pixel");
        let _ = writeln!(s, "cameras:");
        for (name, m) in [("thermal", &self.thermal), ("rgb", &self.rgb)] {
            if let Some(m) = m {
                write_camera_block(&mut s, name, m);
            }
        }
        if let Some(t) = &self.rgb_from_thermal {
            write_extrinsic_block(&mut s, t);
        }
        s
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn rig() -> CalibrationFile {
        let rot = DQuat::from_euler(glam::EulerRot::XYZ, 0.014, -0.009, 0.005);
        CalibrationFile {
            thermal: Some(CameraModel {
                width_px: 160,
                height_px: 120,
                intrinsics: Intrinsics {
                    fx: 147.0,
                    fy: 147.5,
                    cx: 79.3,
                    cy: 59.6,
                },
                distortion: BrownConrady {
                    k1: -0.28,
                    k2: 0.07,
                    p1: 1e-4,
                    p2: -2e-4,
                    k3: 0.0,
                },
            }),
            rgb: Some(CameraModel {
                width_px: 640,
                height_px: 360,
                intrinsics: Intrinsics {
                    fx: 457.0,
                    fy: 457.0,
                    cx: 319.5,
                    cy: 179.5,
                },
                distortion: BrownConrady {
                    k1: 0.09,
                    ..BrownConrady::default()
                },
            }),
            rgb_from_thermal: Some(Rigid3::new(rot, DVec3::new(-0.065, -0.002, 0.003))),
        }
    }

    #[test]
    fn models_round_trip_through_the_file() {
        let c = rig();
        let back = CalibrationFile::parse(Path::new("mem.yaml"), &c.to_yaml())
            .unwrap_or_else(|e| panic!("own output must read back: {e}"));
        for (a, b) in [(&c.thermal, &back.thermal), (&c.rgb, &back.rgb)] {
            let (a, b) = (a.unwrap(), b.unwrap());
            assert_eq!((a.width_px, a.height_px), (b.width_px, b.height_px));
            let (ai, bi) = (a.intrinsics, b.intrinsics);
            for (x, y) in [
                (ai.fx, bi.fx),
                (ai.fy, bi.fy),
                (ai.cx, bi.cx),
                (ai.cy, bi.cy),
            ] {
                assert!((x - y).abs() < 1e-8, "intrinsic {x} read back as {y}");
            }
            assert!((a.distortion.k1 - b.distortion.k1).abs() < 1e-12);
        }
        let (t, u) = (c.rgb_from_thermal.unwrap(), back.rgb_from_thermal.unwrap());
        assert!(
            t.rotation.angle_between(u.rotation) < 1e-9,
            "rotation read back"
        );
        assert!((t.translation_m - u.translation_m).length() < 1e-12);
    }

    #[test]
    fn bad_files_name_the_problem() {
        let p = Path::new("cal.yaml");
        let e = CalibrationFile::parse(p, "format: something-else/2\n").unwrap_err();
        assert!(e.to_string().contains("something-else/2"), "{e}");
        let e = CalibrationFile::parse(p, "format: [unclosed\n").unwrap_err();
        assert!(matches!(e, CalFileError::Syntax { .. }), "{e}");
        let text = rig().to_yaml().replace("fx: 1.47", "fx: -1.47");
        let e = CalibrationFile::parse(p, &text).unwrap_err();
        assert!(e.to_string().contains("thermal"), "negative fx: {e}");
        let text = rig()
            .to_yaml()
            .replace("image_size_px: [160, 120]", "image_size_px: [160]");
        let e = CalibrationFile::parse(p, &text).unwrap_err();
        assert!(
            e.to_string().contains("cameras.thermal.image_size_px"),
            "{e}"
        );
    }
}
