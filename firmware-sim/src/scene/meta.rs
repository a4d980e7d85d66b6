//! The schema of `scene.json`, the description every scene dataset carries: [`SceneJson`]
//! with the joint layout's [`JointJson`] (cameras, rig, truth folders).

use std::collections::BTreeMap;

use s3tir_calib::CameraModel;
use serde::Serialize;

use super::objects::{BACKGROUND_K, ENV_K};
use super::response::ResponseEffects;
use super::truth::TruthSurfaceJson;
use super::{SceneConfig, SceneLayout};

/// `scene.json` (firmware-sim/README.md, `scene`); the joint layout adds `joint`
/// ([`JointJson`]).
#[derive(Debug, Serialize)]
pub(crate) struct SceneJson {
    pub(crate) layout: &'static str,
    pub(crate) world_frame: &'static str,
    pub(crate) env_k: f64,
    pub(crate) background_k: f64,
    pub(crate) camera: CameraModel,
    pub(crate) colmap_camera_model: &'static str,
    pub(crate) pixel_convention: &'static str,
    pub(crate) thermal_units: String,
    pub(crate) depth_units: &'static str,
    pub(crate) temperature_units: &'static str,
    pub(crate) netd_k: f64,
    pub(crate) seed: u64,
    pub(crate) views: usize,
    /// Only in the joint layout (absent from the default layout's file).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) joint: Option<JointJson>,
    /// `truth/surface.ply` ([`super::truth`]): both writers set it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) truth_surface: Option<TruthSurfaceJson>,
}

impl SceneJson {
    /// The fields both layouts share; `images_dir` is where the thermal images are
    /// (`images/` or `images/thermal/`), named in `thermal_units`.
    pub(crate) fn new(
        cfg: &SceneConfig,
        layout: SceneLayout,
        camera: CameraModel,
        effects: ResponseEffects,
        images_dir: &str,
        netd_k: f64,
    ) -> Self {
        Self {
            layout: layout.name(),
            world_frame: match layout {
                SceneLayout::Objects => "x east, y north, z up, metres; ground plane z = 0",
                SceneLayout::Wall | SceneLayout::Facade => {
                    "x east, y north, z up, metres; wall plane y = 0, facing -y"
                }
            },
            env_k: ENV_K,
            background_k: BACKGROUND_K,
            camera,
            colmap_camera_model: "PINHOLE (cx, cy shifted by +0.5 px to COLMAP's pixel convention)",
            pixel_convention: "camera.intrinsics: OpenCV, centre of the top-left pixel at (0, 0)",
            thermal_units: match (effects.agc, effects.drift_step_k > 0.0) {
                (true, _) => format!(
                    "{images_dir}: 8-bit grey, each frame stretched from its own min to max \
                     apparent temperature (automatic gain control; windows in response.json)"
                ),
                (false, true) => format!(
                    "{images_dir}: TLinear centikelvin (apparent black-body temperature x 100) \
                     plus a per-frame drift offset (response.json)"
                ),
                (false, false) => format!(
                    "{images_dir}: TLinear centikelvin (apparent black-body temperature x 100)"
                ),
            },
            depth_units: "depth/: camera z along the pixel-centre ray, millimetres, 0 = no surface",
            temperature_units: "temperature/: true surface temperature along the pixel-centre ray, centikelvin, 0 = no surface",
            netd_k,
            seed: cfg.seed,
            views: cfg.views,
            joint: None,
            truth_surface: None,
        }
    }
}

/// `scene.json`'s `joint` object.
#[derive(Debug, Clone, Serialize)]
pub struct JointJson {
    pub rgb_scale: u32,
    /// Relative exposure of the RGB camera (1, or 0.02 in low light).
    pub rgb_exposure: f64,
    pub low_light: bool,
    /// Full well (signal of a reflectance 1 at exposure 1) and read noise, electrons; the shot
    /// noise is Poisson (Gaussian, σ = √e⁻).
    pub rgb_full_well_e: f64,
    pub rgb_read_noise_e: f64,
    pub thermal_from_rgb: JointTransform,
    /// The RGB camera (OpenCV pixel convention, as `camera`); `camera` is the thermal one.
    pub rgb_camera: CameraModel,
    pub thermal_camera_id: u32,
    pub rgb_camera_id: u32,
    /// How images, poses and the hold-out are laid out.
    pub images: &'static str,
    pub holdout: &'static str,
    /// Each truth folder (relative to the dataset root): camera, size and units. The truth
    /// surface (`truth/surface.ply`, no camera of its own) is `scene.json`'s `truth_surface`.
    pub truth: BTreeMap<&'static str, TruthFolder>,
}

/// A rigid transform in `scene.json`.
#[derive(Debug, Clone, Serialize)]
pub struct JointTransform {
    /// Unit quaternion, Hamilton, order w x y z.
    pub rotation_wxyz: [f64; 4],
    pub translation_m: [f64; 3],
    pub meaning: &'static str,
}

/// One truth folder of `scene.json`'s `joint.truth`.
#[derive(Debug, Clone, Serialize)]
pub struct TruthFolder {
    /// Whose pose: `thermal` or `rgb`.
    pub pose: &'static str,
    pub width_px: u32,
    pub height_px: u32,
    pub units: &'static str,
    pub what: &'static str,
}
