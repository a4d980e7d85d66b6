//! The thermal camera of a folder: where its focal length, principal point and distortion come
//! from, in this order — and the report says which was used:
//! 1. `--calibration FILE` (its thermal camera; must match the images' size);
//! 2. `--focal-px` or `--hfov-deg` on the command line (principal point at the centre,
//!    distortion `--k1`, default none);
//! 3. EXIF's 35 mm-equivalent focal length (`FocalLengthIn35mmFormat`: the horizontal field of
//!    view of a 36 mm wide frame);
//! 4. [`KNOWN_CAMERAS`]: thermal cores whose field of view (and distortion, where measured) is
//!    known by the EXIF make and model their files carry;
//! 5. otherwise an error asking for one of the above.

use std::path::PathBuf;

use serde::Serialize;

use super::super::PosesError;
use super::scan::Folder;
use crate::model::calfile::CalibrationFile;
use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};

/// A thermal camera whose geometry is known by its EXIF make and model.
#[derive(Debug, Clone, Copy)]
pub struct KnownCamera {
    pub make: &'static str,
    pub model: &'static str,
    /// What the camera is (for the report).
    pub name: &'static str,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f64,
    /// Radial distortion k1 (OpenCV), at the stored image size.
    pub k1: f64,
    /// Where the figures come from.
    pub source: &'static str,
}

/// Known thermal cameras.
pub const KNOWN_CAMERAS: &[KnownCamera] = &[KnownCamera {
    make: "DJI",
    model: "FC2403",
    name: "DJI Mavic 2 Enterprise Dual, thermal (160×120 Lepton, stored at 640×480)",
    hfov_deg: 57.0,
    k1: -0.28,
    source: "field of view from DJI's specification (57°); k1 measured on the thermal-facade set (the eave's straightness in four top-row frames: −0.22 to −0.35)",
}];

/// Where the intrinsics came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "from")]
pub enum IntrinsicsSource {
    Calibration { path: PathBuf },
    CommandLine,
    Exif35mm { focal_35mm: f64 },
    KnownCamera { camera: String, source: String },
}

/// The command line's say on the intrinsics.
#[derive(Debug, Clone, Default)]
pub struct IntrinsicsArgs {
    pub calibration: Option<(PathBuf, CalibrationFile)>,
    pub focal_px: Option<f64>,
    pub hfov_deg: Option<f64>,
    pub k1: Option<f64>,
}

fn pinhole(w: usize, h: usize, f: f64, k1: f64) -> CameraModel {
    CameraModel {
        width_px: w as u32,
        height_px: h as u32,
        intrinsics: Intrinsics {
            fx: f,
            fy: f,
            cx: (w as f64 - 1.0) / 2.0,
            cy: (h as f64 - 1.0) / 2.0,
        },
        distortion: BrownConrady {
            k1,
            ..BrownConrady::default()
        },
    }
}

fn focal_of_hfov(w: usize, hfov_deg: f64) -> f64 {
    w as f64 / 2.0 / (hfov_deg.to_radians() / 2.0).tan()
}

/// The folder's thermal camera (module docs).
pub fn thermal_camera(
    folder: &Folder,
    args: &IntrinsicsArgs,
) -> Result<(CameraModel, IntrinsicsSource), PosesError> {
    let first = &folder.shots[0];
    let (w, h) = (first.width, first.height);
    if let Some((path, cal)) = &args.calibration {
        let cam = cal.thermal.ok_or_else(|| PosesError::MissingCalibration {
            what: "thermal camera",
            why: format!("{} has none", path.display()),
        })?;
        if (cam.width_px as usize, cam.height_px as usize) != (w, h) {
            return Err(PosesError::Folder {
                path: folder.dir.clone(),
                reason: format!(
                    "the thermal images are {w}×{h} px but {} calibrates the thermal camera at {}×{} px",
                    path.display(),
                    cam.width_px,
                    cam.height_px
                ),
            });
        }
        return Ok((cam, IntrinsicsSource::Calibration { path: path.clone() }));
    }
    let bad = |reason: String| PosesError::Folder {
        path: folder.dir.clone(),
        reason,
    };
    if let Some(f) = args.focal_px {
        if !(f.is_finite() && f > 0.0) {
            return Err(bad(format!(
                "--focal-px {f}: a positive focal length expected"
            )));
        }
        return Ok((
            pinhole(w, h, f, args.k1.unwrap_or(0.0)),
            IntrinsicsSource::CommandLine,
        ));
    }
    if let Some(a) = args.hfov_deg {
        if !(a > 1.0 && a < 179.0) {
            return Err(bad(format!("--hfov-deg {a}: 1–179° expected")));
        }
        return Ok((
            pinhole(w, h, focal_of_hfov(w, a), args.k1.unwrap_or(0.0)),
            IntrinsicsSource::CommandLine,
        ));
    }
    if let Some(f35) = first.meta.focal_length_35mm.filter(|f| *f > 0.0) {
        let hfov = 2.0 * (18.0 / f35).atan().to_degrees();
        return Ok((
            pinhole(w, h, focal_of_hfov(w, hfov), args.k1.unwrap_or(0.0)),
            IntrinsicsSource::Exif35mm { focal_35mm: f35 },
        ));
    }
    let (make, model) = (
        first.meta.make.as_deref().unwrap_or("").trim(),
        first.meta.model.as_deref().unwrap_or("").trim(),
    );
    if let Some(k) = KNOWN_CAMERAS
        .iter()
        .find(|k| k.make.eq_ignore_ascii_case(make) && k.model.eq_ignore_ascii_case(model))
    {
        return Ok((
            pinhole(w, h, focal_of_hfov(w, k.hfov_deg), args.k1.unwrap_or(k.k1)),
            IntrinsicsSource::KnownCamera {
                camera: k.name.to_owned(),
                source: k.source.to_owned(),
            },
        ));
    }
    Err(bad(format!(
        "no focal length for the thermal camera ({}): its files carry no 35 mm-equivalent focal length and {} is not a camera this tool knows; pass --calibration FILE, --hfov-deg (the camera's horizontal field of view) or --focal-px",
        first.name,
        if make.is_empty() && model.is_empty() {
            "it".to_owned()
        } else {
            format!("{make} {model}")
        }
    )))
}
