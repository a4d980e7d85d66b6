//! The rig's calibration for the stage: the one given or the one attached to the session,
//! checked against the frames the session records.

use super::PosesError;
use super::frames::SessionScan;
use crate::model::calfile::CalibrationFile;
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;

/// Everything the stage needs of a calibration, checked against the session.
#[derive(Debug, Clone, Copy)]
pub struct RigModels {
    pub thermal: CameraModel,
    /// RGB camera and `rgb_from_thermal`, when the session records RGB.
    pub rgb: Option<(CameraModel, Rigid3)>,
}

/// Checks the calibration against the frames the session records.
pub fn rig_models(cal: &CalibrationFile, scan: &SessionScan) -> Result<RigModels, PosesError> {
    let thermal = cal.thermal.ok_or(PosesError::MissingCalibration {
        what: "thermal camera",
        why: "every posed view is a thermal view".into(),
    })?;
    let check = |camera: &'static str, m: &CameraModel, size: Option<(u32, u32)>| match size {
        Some((w, h)) if (w, h) != (m.width_px, m.height_px) => {
            Err(PosesError::CalibrationMismatch {
                camera,
                session: scan.path.clone(),
                calibrated_w: m.width_px,
                calibrated_h: m.height_px,
                session_w: w,
                session_h: h,
            })
        }
        _ => Ok(()),
    };
    check("thermal", &thermal, scan.thermal_size)?;
    let rgb = match scan.rgb_size {
        None => None,
        Some(_) => {
            let rgb = cal.rgb.ok_or(PosesError::MissingCalibration {
                what: "RGB camera",
                why: format!(
                    "session {} records RGB frames, and structure from motion runs on them",
                    scan.path.display()
                ),
            })?;
            check("rgb", &rgb, scan.rgb_size)?;
            let e = cal.rgb_from_thermal.ok_or(PosesError::MissingCalibration {
                what: "rgb_from_thermal extrinsic",
                why: "thermal poses are the RGB poses composed with it (calibrate from thermal + RGB pairs)".into(),
            })?;
            Some((rgb, e))
        }
    };
    Ok(RigModels { thermal, rgb })
}

/// The calibration attached to a session (`s3tir-capture --calibration FILE`).
pub fn attached_calibration(scan: &SessionScan) -> Result<CalibrationFile, PosesError> {
    let mut problems = Vec::new();
    for (name, data) in &scan.attachments {
        if !name.starts_with("calibration") {
            continue;
        }
        let label = scan.path.join(name);
        match CalibrationFile::parse(&label, &String::from_utf8_lossy(data)) {
            Ok(c) => return Ok(c),
            Err(e) => problems.push(s3tir_capture::Chain(&e).to_string()),
        }
    }
    Err(PosesError::MissingCalibration {
        what: "file",
        why: if problems.is_empty() {
            format!(
                "none was given (--calibration FILE) and session {} carries none (record with s3tir-capture --calibration FILE)",
                scan.path.display()
            )
        } else {
            format!(
                "none was given (--calibration FILE) and the one attached to session {} does not read: {}",
                scan.path.display(),
                problems.join("; ")
            )
        },
    })
}
