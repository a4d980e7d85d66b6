//! RGB partners in a folder's dataset (`--with-rgb`), for joint RGB + thermal training: the
//! same layout the session stage writes ([`crate::poses::dataset`]) — the calibrated RGB
//! camera as camera 2 ([`crate::poses::dataset::RGB_CAMERA_ID`]), each partner as
//! `images/rgb_STEM.png` (8-bit RGB, lossless, **not undistorted**: the trainer undistorts at
//! load), its pose in the thermal views' world, the partner of a held-out thermal view held
//! out too.
//!
//! **Where an RGB pose comes from**, per partner:
//! 1. the board method: PnP on the board in the RGB image itself, with the calibrated RGB
//!    camera ([`super::board::pose_partners`]). Each modality is then posed by its own
//!    measurement in the board's frame, so a pair that is not one rigid instant (a dual camera
//!    whose two shutters fire apart, a hand that moved) costs nothing but the check below;
//! 2. structure from motion on the partners ([`super::sfm`]): COLMAP's pose of the partner;
//! 3. otherwise (another method, or the board not found in the partner): the thermal pose
//!    composed with the calibrated extrinsic, `world_from_rgb = world_from_thermal ∘
//!    rgb_from_thermal⁻¹` (the lever arm in metres: the board's world, east-north-up, or
//!    scaled; in COLMAP's unscaled world the extrinsic's rotation only, as the stage passes it);
//! 4. none: the RGB view is left out, with that reason (its thermal view stays).
//!
//! The check: the distance between each PnP-posed pair's two camera centres, reported (median
//! and largest) beside the calibrated lever arm. It is not a reason to drop a view — each image
//! is posed where it was taken — but a gap far above the lever arm says the pair is not one
//! instant (sun-board's pairs: see its calibration's warnings), which a joint run's
//! gradient-alignment loss assumes.
//!
//! Needs `--calibration` with the RGB camera (its size must be the partners'): the folder's
//! own calibration (`s3tir-calib DIR --out calibration.yaml`) gives it.

use std::path::Path;

use serde::Serialize;

use super::super::PosesError;
use super::super::board::BoardFiducial;
use super::super::stats::{median, percentile};
use super::intrinsics::IntrinsicsArgs;
use super::scan::Folder;
use super::{Method, Posing};
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::progress::Progress;

/// The RGB camera and the extrinsic, from the calibration (checked against the partners).
#[derive(Debug, Clone, Copy)]
pub struct RgbRig {
    pub camera: CameraModel,
    pub rgb_from_thermal: Option<Rigid3>,
}

/// Where the RGB poses came from and how they agree with the thermal ones (`poses.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct RgbFigures {
    /// Posed thermal shots with an RGB partner.
    pub partners: usize,
    /// RGB views written (held-out ones included).
    pub views: usize,
    pub held_out: usize,
    /// Posed by PnP on the board in the RGB image.
    pub from_board: usize,
    /// Posed by structure from motion on the partners themselves.
    pub from_sfm: usize,
    /// Posed by the calibrated extrinsic.
    pub from_extrinsic: usize,
    /// PnP reprojection RMS, pixels (median; board method).
    pub pnp_rms_px_median: Option<f64>,
    /// Distance between a pair's two camera centres, metres: median and largest (PnP-posed
    /// partners only: the extrinsic's pairs are at the lever arm by construction).
    pub centre_gap_m: Option<[f64; 2]>,
    /// The calibrated lever arm's length, metres.
    pub lever_arm_m: Option<f64>,
}

/// One posed RGB view: the thermal shot it partners and its pose.
#[derive(Debug, Clone, Copy)]
pub struct RgbView {
    pub shot: usize,
    pub world_from_rgb: Rigid3,
}

/// The posed partners: views, those left out (by thermal shot, with the reason), figures.
#[derive(Debug, Clone)]
pub struct RgbPosing {
    pub views: Vec<RgbView>,
    pub left_out: Vec<(usize, String)>,
    pub figures: RgbFigures,
}

/// The RGB camera for `--with-rgb`, checked against the folder (module docs). Raised before
/// anything is written.
pub fn rgb_rig(
    folder: &Folder,
    intrinsics: &IntrinsicsArgs,
    method: Method,
) -> Result<RgbRig, PosesError> {
    let Some(first) = folder.shots.iter().find_map(|s| s.rgb.as_ref()) else {
        return Err(PosesError::Folder {
            path: folder.dir.clone(),
            reason: "--with-rgb: no thermal image has an RGB partner (thermal/ and rgb/ subfolders paired by name, DJI _T/_W names, or two image sizes paired by capture time)".to_owned(),
        });
    };
    let Some((path, cal)) = &intrinsics.calibration else {
        return Err(PosesError::MissingCalibration {
            what: "RGB camera for --with-rgb",
            why: "no --calibration given (calibrate the folder first: s3tir-calib DIR --out calibration.yaml with DIR/board.toml)".to_owned(),
        });
    };
    let camera = cal.rgb.ok_or_else(|| PosesError::MissingCalibration {
        what: "RGB camera for --with-rgb",
        why: format!("{} calibrates no RGB camera", path.display()),
    })?;
    let (w, h) = image::image_dimensions(first).map_err(|e| PosesError::ImageRead {
        path: first.clone(),
        source: Box::new(e),
    })?;
    if (w, h) != (camera.width_px, camera.height_px) {
        return Err(PosesError::Folder {
            path: first.clone(),
            reason: format!(
                "the RGB partner is {w}×{h} px but {} calibrates the RGB camera at {}×{} px",
                path.display(),
                camera.width_px,
                camera.height_px
            ),
        });
    }
    if method != Method::Board && cal.rgb_from_thermal.is_none() {
        return Err(PosesError::MissingCalibration {
            what: "rgb_from_thermal extrinsic for --with-rgb",
            why: format!(
                "{} has none, and outside the board method the RGB poses are the thermal poses composed with it",
                path.display()
            ),
        });
    }
    Ok(RgbRig {
        camera,
        rgb_from_thermal: cal.rgb_from_thermal,
    })
}

/// Poses the posed thermal shots' RGB partners (module docs).
pub fn pose_rgb(
    folder: &Folder,
    posing: &Posing,
    rig: &RgbRig,
    board: Option<&BoardFiducial>,
    progress: &dyn Progress,
) -> Result<RgbPosing, PosesError> {
    let with_partner: Vec<(usize, Rigid3)> = posing
        .posed
        .iter()
        .filter(|(i, _)| folder.shots[*i].rgb.is_some())
        .copied()
        .collect();
    let pnp = match board {
        Some(b) => super::board::pose_partners(folder, &rig.camera, b, &with_partner, progress)?,
        None => vec![None; with_partner.len()],
    };
    let measured: std::collections::BTreeMap<usize, Rigid3> =
        posing.rgb_poses.iter().copied().collect();
    let mut figures = RgbFigures {
        partners: with_partner.len(),
        lever_arm_m: rig.rgb_from_thermal.map(|e| e.translation_m.length()),
        ..RgbFigures::default()
    };
    let (mut views, mut left_out, mut rms, mut gaps) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for ((shot, world_from_thermal), by_board) in with_partner.iter().zip(pnp) {
        let pose = match by_board {
            _ if measured.contains_key(shot) => {
                figures.from_sfm += 1;
                measured.get(shot).copied()
            }
            Some(p) => {
                figures.from_board += 1;
                rms.push(p.rms_px);
                gaps.push(
                    (p.world_from_cam.translation_m - world_from_thermal.translation_m).length(),
                );
                Some(p.world_from_cam)
            }
            None => rig.rgb_from_thermal.map(|e| {
                figures.from_extrinsic += 1;
                world_from_thermal.compose(&e.inverse())
            }),
        };
        match pose {
            Some(world_from_rgb) => views.push(RgbView {
                shot: *shot,
                world_from_rgb,
            }),
            None => left_out.push((
                *shot,
                "the board is not found in its RGB partner and the calibration has no extrinsic"
                    .to_owned(),
            )),
        }
    }
    figures.pnp_rms_px_median = (!rms.is_empty()).then(|| median(&rms));
    figures.centre_gap_m = (!gaps.is_empty()).then(|| [median(&gaps), percentile(&gaps, 1.0)]);
    Ok(RgbPosing {
        views,
        left_out,
        figures,
    })
}

/// Decodes an RGB partner and writes it as 8-bit RGB PNG.
pub fn write_partner(src: &Path, dst: &Path) -> Result<(), PosesError> {
    let img = image::open(src).map_err(|e| PosesError::ImageRead {
        path: src.to_path_buf(),
        source: Box::new(e),
    })?;
    img.to_rgb8().save(dst).map_err(|e| PosesError::Write {
        path: dst.to_path_buf(),
        source: Box::new(e),
    })
}
