//! The folder stage's options as command-line flags, declared once: `s3tir-calib poses DIR`
//! flattens [`FolderArgs`] (the doc comments below are its `--help`); defaults are read from
//! [`FolderOptions::default`] and [`PlaneOptions::default`].

use clap::Args;
use s3tir_capture::radiometric::{ConditionOverrides, Units};

use super::plane::PlaneOptions;
use super::sfm::SfmOptions;
use super::{FolderOptions, Method};
use crate::poses::PosesOptions;
use crate::poses::folder::intrinsics::IntrinsicsArgs;

/// How a folder of images is read and posed.
#[derive(Debug, Clone, Args)]
pub struct FolderArgs {
    /// Folder input: how the shots are posed. auto: the board method with --board; else the
    /// planar method when every shot has GPS and gimbal angles and the gimbal keeps its heading
    /// and pitch (a survey of a wall or of the ground); else structure from motion (COLMAP, on
    /// the RGB partners when --calibration has their camera and the extrinsic; GPS positions,
    /// when the files have them, make the world east-north-up metres).
    #[arg(long, value_enum, default_value = "auto")]
    pub method: Method,
    /// Folder input: what 16-bit or float grey TIFF/PNG values are (kelvin, decikelvin,
    /// centikelvin, millikelvin, celsius, decicelsius, centicelsius, millicelsius, or raw
    /// counts); radiometric JPEGs and 8-bit pictures need none.
    #[arg(long = "image-units")]
    pub image_units: Option<Units>,
    #[command(flatten)]
    pub conditions: ConditionOverrides,
    /// Folder input: the thermal camera's focal length in pixels (at the images' size),
    /// when neither --calibration nor the files give it.
    #[arg(long, conflicts_with = "hfov_deg")]
    pub focal_px: Option<f64>,
    /// Folder input: the thermal camera's horizontal field of view, degrees (instead of
    /// --focal-px).
    #[arg(long)]
    pub hfov_deg: Option<f64>,
    /// Folder input: radial distortion k1 (OpenCV) with --focal-px/--hfov-deg [default: 0, or
    /// the known camera's].
    #[arg(long)]
    pub k1: Option<f64>,
    /// Planar method: the wall's shift in pixels per metre of camera motion (the focal length
    /// in pixels ÷ the distance to the wall) [default: measured].
    #[arg(long)]
    pub px_per_m: Option<f64>,
    /// Planar method: register shots whose GPS positions are this close, metres.
    #[arg(long, default_value_t = PlaneOptions::default().pair_m)]
    pub pair_m: f64,
    /// Planar method: search radius around the shift the GPS predicts, pixels.
    #[arg(long, default_value_t = PlaneOptions::default().search_px)]
    pub search_px: f64,
    /// Planar and structure-from-motion methods: σ of the GPS positions, metres.
    #[arg(long, default_value_t = PlaneOptions::default().gps_sigma_m)]
    pub gps_sigma_m: f64,
    /// Folder input: at most this many seed points in the dataset.
    #[arg(long, default_value_t = FolderOptions::default().max_points)]
    pub max_points: usize,
}

impl FolderArgs {
    /// The stage's options (`intrinsics`: the calibration, when given; `session`: the posing
    /// flags a folder shares with a session — `--colmap`, `--matcher`, `--metres-per-unit`,
    /// `--with-rgb`; hold-out and progress are the caller's).
    pub fn options(&self, calibration: IntrinsicsArgs, session: &PosesOptions) -> FolderOptions {
        FolderOptions {
            method: self.method,
            units: self.image_units,
            conditions: self.conditions,
            intrinsics: IntrinsicsArgs {
                focal_px: self.focal_px,
                hfov_deg: self.hfov_deg,
                k1: self.k1,
                ..calibration
            },
            plane: PlaneOptions {
                px_per_m: self.px_per_m,
                pair_m: self.pair_m,
                search_px: self.search_px,
                gps_sigma_m: self.gps_sigma_m,
                ..PlaneOptions::default()
            },
            sfm: SfmOptions {
                colmap: session.colmap.clone(),
                matcher: session.matcher,
                metres_per_unit: session.metres_per_unit,
                gps_sigma_m: self.gps_sigma_m,
            },
            with_rgb: session.with_rgb,
            max_points: self.max_points,
            ..FolderOptions::default()
        }
    }
}
