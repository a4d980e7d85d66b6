//! The joint RGB + thermal layout of the scene datasets (`scene --rgb-scale K`), for training
//! a model on both cameras at once (TGA-GS) and scoring its thermal render at the RGB
//! camera's resolution against high-resolution truth.
//!
//! Same scenes as [`super`] (layouts, world frame, surfaces, sensor models); what
//! changes is the rig. With `W × H` the thermal resolution and `K` the RGB scale (1 to
//! [`MAX_RGB_SCALE`]):
//!
//! - **Cameras.** Thermal: [`scene_camera`]`(W, H)`, COLMAP camera 1. RGB:
//!   [`scene_camera`]`(K·W, K·H)`, COLMAP camera 2: the same 57° field of view, `K` times the
//!   pixels (a thermal pixel covers exactly `K × K` RGB pixels of the same pose). Both
//!   `PINHOLE`, `cx, cy` + ½ px in `cameras.txt` (COLMAP's pixel convention).
//! - **Poses.** [`poses`]`(layout, views)` gives the RGB camera's `cam_from_world` at each
//!   instant k; the thermal camera is rigidly mounted beside it, [`thermal_from_rgb`]: no
//!   rotation, `X_thermal = X_rgb + (0.03, 0, 0) m` (3 cm to the RGB camera's left, seen
//!   from behind). Thermal `cam_from_world = thermal_from_rgb ∘ rgb_cam_from_world`.
//! - **Images** (COLMAP names relative to `images/`): instant k is image `2k+1`
//!   `thermal/NNNN.png` (camera 1) and image `2k+2` `rgb/NNNN.png` (camera 2). The thermal
//!   frame is made exactly as the default layout's `images/NNNN.png` (area-averaged render,
//!   PSF blur, the Lepton's noise, the response effects `--agc` / `--drift-k`); the RGB frame
//!   is rendered at `K·W × K·H`, blurred (σ 0.5 px) and exposed with shot and read noise at
//!   exposure 1, or 0.02 with `low_light` ([`JointOptions`]), 8-bit sRGB.
//! - **`holdout.txt`**: both names of every instant k with k % [`HOLDOUT_EVERY`] == 0.
//! - **Truth** under `truth/`, mirroring the image names:
//!   - `apparent/thermal/NNNN.png`: apparent temperature (centikelvin u16) of the
//!     area-averaged radiance at the thermal camera, `W × H`, no blur, no noise;
//!   - `apparent_sr/thermal/NNNN.png`: the same at the thermal pose rendered with the
//!     `K·W × K·H` camera: what a model's K× thermal render is scored against;
//!   - `depth/thermal/NNNN.png` (`W × H`) and `depth/rgb/NNNN.png` (`K·W × K·H`): camera z
//!     along the pixel-centre ray, millimetres u16, 0 = no surface;
//!   - `rgb/rgb/NNNN.png`: the RGB input without blur or noise, at the input's exposure,
//!     8-bit sRGB (what a perfect model renders);
//!   - `surface.ply`: the visible surface with its apparent temperature (kelvin, emissivity 1),
//!     traced at every instant's **thermal** pose with the thermal camera at 2× its resolution,
//!     one point per 4 mm cube ([`super::truth`]; the same file as the default layout's).
//! - `sparse/0/points3D.txt` as in the default layout; `scene.json` with a `joint` object
//!   ([`JointJson`], whose `truth` lists the per-image truth folders) and, as in the default
//!   layout, `truth_surface` ([`super::truth::TruthSurfaceJson`]); `response.json` /
//!   `ffc.txt` with the response effects, naming `thermal/NNNN.png`.
//!
//! The default layout's `images/NNNN.png`, `rgb/`, `depth/` and `temperature/` are not written.

use std::collections::BTreeMap;
use std::path::PathBuf;

use glam::{DQuat, DVec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use s3tir_calib::model::colmap::ColmapImage;
use s3tir_calib::{CameraModel, Rigid3};

use super::cameras::{poses, scene_camera};
use super::files::{
    centikelvin_words, colmap_image, create_dirs, depth_mm_words, io, save_exported, save_rgb8,
    save_u16, write_colmap_text, write_json, write_response_files,
};
use super::meta::SceneJson;
pub use super::meta::{JointJson, JointTransform, TruthFolder};
use super::objects::sample_surface_points;
use super::render::render_scene;
use super::response::{ResponseEffects, ResponseSimulator};
use super::sensing::{expose_scene_rgb, scene_thermal_profile, sense_thermal};
use super::truth::{
    SURFACE_TRUTH_FILE, SURFACE_WHAT_JOINT, TruthSurfaceJson, surface_camera,
    write_surface_truth_with,
};
use super::{SceneConfig, SceneLayout, check_scene_config};
use crate::error::SimError;
use crate::physics::Radiometry;
use crate::render::RayGrid;
use crate::sensor::{RgbProfile, ThermalSensor, expose_rgb_channels_noise_free};

/// The largest RGB scale: the RGB camera has at most 8× the thermal resolution per axis.
pub const MAX_RGB_SCALE: u32 = 8;
/// Instants whose two images are held out: every k with k % `HOLDOUT_EVERY` == 0.
pub const HOLDOUT_EVERY: usize = 8;
/// Translation of [`thermal_from_rgb`], metres: `X_thermal = X_rgb + THERMAL_FROM_RGB_M`.
pub const THERMAL_FROM_RGB_M: DVec3 = DVec3::new(0.03, 0.0, 0.0);
/// COLMAP camera id of the thermal camera.
pub const THERMAL_CAMERA_ID: u32 = 1;
/// COLMAP camera id of the RGB camera.
pub const RGB_CAMERA_ID: u32 = 2;

/// What the joint layout adds to a scene dataset (`scene --rgb-scale K [--low-light]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JointOptions {
    /// The RGB camera has `rgb_scale` times the thermal resolution per axis (1 ..=
    /// [`MAX_RGB_SCALE`]).
    pub rgb_scale: u32,
    /// RGB exposed at 2 % ([`RgbProfile::hd720_low_light`]) instead of 1.
    pub low_light: bool,
}

impl JointOptions {
    /// The options of the command-line flags `--rgb-scale` and `--low-light`: `None` for the
    /// default layout (`rgb_scale` 0, no low light); an error for a scale above
    /// [`MAX_RGB_SCALE`] or low light without a scale.
    pub fn from_flags(rgb_scale: u32, low_light: bool) -> Result<Option<Self>, SimError> {
        if rgb_scale == 0 {
            if low_light {
                return Err(SimError::InvalidParameter {
                    parameter: "low_light (--low-light)",
                    value: "true".into(),
                    why: "low light is the RGB exposure of the joint layout: it needs \
                          --rgb-scale K (1 to 8)",
                });
            }
            return Ok(None);
        }
        let options = Self {
            rgb_scale,
            low_light,
        };
        options.validate()?;
        Ok(Some(options))
    }

    /// Checks the scale is within 1 ..= [`MAX_RGB_SCALE`].
    pub fn validate(&self) -> Result<(), SimError> {
        if !(1..=MAX_RGB_SCALE).contains(&self.rgb_scale) {
            return Err(SimError::InvalidParameter {
                parameter: "rgb_scale (--rgb-scale)",
                value: self.rgb_scale.to_string(),
                why: "the RGB camera has 1 to 8 times the thermal resolution per axis \
                      (0: the default layout, no joint RGB camera)",
            });
        }
        Ok(())
    }

    /// The RGB camera's relative exposure: 1, or the low-light profile's 0.02.
    pub fn rgb_exposure(&self) -> f64 {
        if self.low_light {
            RgbProfile::hd720_low_light().exposure
        } else {
            RgbProfile::hd720().exposure
        }
    }

    /// The RGB camera of a `width_px × height_px` thermal camera: [`scene_camera`] at
    /// `rgb_scale` times the size.
    pub fn rgb_camera(&self, width_px: u32, height_px: u32) -> Result<CameraModel, SimError> {
        self.validate()?;
        match (
            width_px.checked_mul(self.rgb_scale),
            height_px.checked_mul(self.rgb_scale),
        ) {
            (Some(w), Some(h)) => Ok(scene_camera(w, h)),
            _ => Err(SimError::InvalidParameter {
                parameter: "width/height x rgb_scale",
                value: format!("{width_px}x{height_px} x {}", self.rgb_scale),
                why: "the RGB image size overflows 32 bits",
            }),
        }
    }
}

/// The rig's `thermal_from_rgb`: no rotation, translation [`THERMAL_FROM_RGB_M`].
pub fn thermal_from_rgb() -> Rigid3 {
    Rigid3::new(DQuat::IDENTITY, THERMAL_FROM_RGB_M)
}

/// The thermal camera's `cam_from_world` at the instant the RGB camera's is
/// `rgb_cam_from_world`: `thermal_from_rgb ∘ rgb_cam_from_world`.
pub fn thermal_cam_from_world(rgb_cam_from_world: &Rigid3) -> Rigid3 {
    thermal_from_rgb().compose(rgb_cam_from_world)
}

/// The COLMAP names (relative to `images/`) of instant `k`: thermal, RGB.
pub fn image_names(k: usize) -> (String, String) {
    (format!("thermal/{k:04}.png"), format!("rgb/{k:04}.png"))
}

/// Writes the joint RGB + thermal scene dataset of `layout` (module docs) into
/// `cfg.out_dir`; `cfg.width_px × cfg.height_px` is the thermal resolution. `effects` apply to
/// the thermal images as in [`super::write_scene_set_with`]. `progress(done, views)` is
/// called after each instant.
pub fn write_joint_scene_set(
    cfg: &SceneConfig,
    layout: SceneLayout,
    effects: ResponseEffects,
    joint: &JointOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(), SimError> {
    check_scene_config(cfg)?;
    let thermal_cam = scene_camera(cfg.width_px, cfg.height_px);
    let rgb_cam = joint.rgb_camera(cfg.width_px, cfg.height_px)?;
    let out = &cfg.out_dir;
    create_dirs(
        out,
        &[
            "sparse/0",
            "images/thermal",
            "images/rgb",
            "truth/apparent/thermal",
            "truth/apparent_sr/thermal",
            "truth/depth/thermal",
            "truth/depth/rgb",
            "truth/rgb/rgb",
        ],
    )?;
    let mut writer = InstantWriter::new(cfg, layout, effects, joint, thermal_cam, rgb_cam);
    let mut index = JointIndex::with_capacity(cfg.views);
    for (k, rgb_from_world) in poses(layout, cfg.views).iter().enumerate() {
        let (thermal_name, rgb_name) = image_names(k);
        let thermal_from_world = writer.write_instant(&thermal_name, &rgb_name, rgb_from_world)?;
        index.add(
            k,
            thermal_name,
            rgb_name,
            thermal_from_world,
            rgb_from_world,
        )?;
        progress(k + 1, cfg.views);
    }
    let thermal_poses = index.write(cfg, layout, thermal_cam, rgb_cam)?;
    // The visible surface at every instant's thermal pose, for scoring meshes.
    let surface_path = out.join(SURFACE_TRUTH_FILE);
    let surface_n = write_surface_truth_with(
        &surface_path,
        layout,
        &thermal_cam,
        &thermal_poses,
        &writer.radiometry,
    )?;
    write_response_files(out, effects, &writer.response)?;
    let meta = writer.scene_json(surface_n)?;
    write_json(&out.join("scene.json"), &meta, "scene.json")
}

/// Renders, senses and saves each instant's images and truth (module docs, "Images" and
/// "Truth"); holds the sensor and noise streams that run across the instants.
struct InstantWriter<'a> {
    cfg: &'a SceneConfig,
    layout: SceneLayout,
    effects: ResponseEffects,
    joint: &'a JointOptions,
    thermal_cam: CameraModel,
    rgb_cam: CameraModel,
    thermal_grid: RayGrid,
    /// The RGB camera's grid serves the super-resolved thermal truth too (same camera model).
    rgb_grid: RayGrid,
    sensor: ThermalSensor,
    radiometry: Radiometry,
    rgb_profile: RgbProfile,
    /// The RGB camera's shot and read noise.
    rng: ChaCha8Rng,
    response: ResponseSimulator,
    /// [`thermal_from_rgb`].
    rig: Rigid3,
    images_dir: PathBuf,
    truth: PathBuf,
}

impl<'a> InstantWriter<'a> {
    /// The cameras' grids, the sensor models and the noise streams, seeded from `cfg.seed`.
    fn new(
        cfg: &'a SceneConfig,
        layout: SceneLayout,
        effects: ResponseEffects,
        joint: &'a JointOptions,
        thermal_cam: CameraModel,
        rgb_cam: CameraModel,
    ) -> Self {
        Self {
            cfg,
            layout,
            effects,
            joint,
            thermal_cam,
            rgb_cam,
            thermal_grid: RayGrid::new(&thermal_cam),
            rgb_grid: RayGrid::new(&rgb_cam),
            sensor: ThermalSensor::new(scene_thermal_profile(thermal_cam), cfg.seed),
            radiometry: Radiometry::new(),
            rgb_profile: RgbProfile {
                camera: rgb_cam,
                exposure: joint.rgb_exposure(),
                ..RgbProfile::hd720()
            },
            rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5C3E),
            response: ResponseSimulator::new(effects, cfg.seed),
            rig: thermal_from_rgb(),
            images_dir: cfg.out_dir.join("images"),
            truth: cfg.out_dir.join("truth"),
        }
    }

    /// Writes the thermal and RGB images of the instant whose RGB pose is `rgb_from_world`,
    /// with their truth; returns the thermal pose.
    fn write_instant(
        &mut self,
        thermal_name: &str,
        rgb_name: &str,
        rgb_from_world: &Rigid3,
    ) -> Result<Rigid3, SimError> {
        let thermal_from_world = self.rig.compose(rgb_from_world);
        self.write_thermal(thermal_name, &thermal_from_world)?;
        self.write_rgb(rgb_name, rgb_from_world)?;
        Ok(thermal_from_world)
    }

    /// The thermal input and its truth at the thermal resolution, then the super-resolved
    /// thermal truth: the thermal pose through the RGB-sized camera.
    fn write_thermal(&mut self, name: &str, thermal_from_world: &Rigid3) -> Result<(), SimError> {
        let (w, h) = (self.thermal_cam.width_px, self.thermal_cam.height_px);
        let (rw, rh) = (self.rgb_cam.width_px, self.rgb_cam.height_px);
        let r = render_scene(
            self.layout,
            &self.thermal_grid,
            thermal_from_world,
            &self.radiometry,
        );
        let words = sense_thermal(&mut self.sensor, &r.radiance, w, h)?;
        let exported = self.response.export(name, &words);
        save_exported(&self.images_dir.join(name), w, h, exported)?;
        let apparent = self.apparent_ck(&r.radiance);
        save_u16(&self.truth.join("apparent").join(name), w, h, apparent)?;
        let depth = depth_mm_words(&r.depth_m);
        save_u16(&self.truth.join("depth").join(name), w, h, depth)?;
        drop(r);
        let sr = render_scene(
            self.layout,
            &self.rgb_grid,
            thermal_from_world,
            &self.radiometry,
        );
        let apparent_sr = self.apparent_ck(&sr.radiance);
        save_u16(
            &self.truth.join("apparent_sr").join(name),
            rw,
            rh,
            apparent_sr,
        )
    }

    /// The RGB input, its noise-free (and blur-free) truth and its depth.
    fn write_rgb(&mut self, name: &str, rgb_from_world: &Rigid3) -> Result<(), SimError> {
        let (rw, rh) = (self.rgb_cam.width_px, self.rgb_cam.height_px);
        let c = render_scene(
            self.layout,
            &self.rgb_grid,
            rgb_from_world,
            &self.radiometry,
        );
        let rgb = expose_scene_rgb(&self.rgb_profile, &c, rw, rh, &mut self.rng);
        save_rgb8(&self.images_dir.join(name), rw, rh, rgb)?;
        let [c0, c1, c2] = &c.rgb_linear;
        let clean = expose_rgb_channels_noise_free(&self.rgb_profile, [c0, c1, c2]);
        save_rgb8(&self.truth.join("rgb").join(name), rw, rh, clean)?;
        let depth = depth_mm_words(&c.depth_m);
        save_u16(&self.truth.join("depth").join(name), rw, rh, depth)
    }

    /// Apparent temperature (centikelvin words) of in-band radiance.
    fn apparent_ck(&self, radiance: &[f64]) -> Vec<u16> {
        let t: Vec<f64> = radiance
            .iter()
            .map(|&l| self.radiometry.temperature_k(l))
            .collect();
        centikelvin_words(&t)
    }

    /// `scene.json`: the shared fields, the joint layout's units, [`JointJson`] and the
    /// truth surface of `surface_n` points.
    fn scene_json(&self, surface_n: usize) -> Result<SceneJson, SimError> {
        let (w, h) = (self.thermal_cam.width_px, self.thermal_cam.height_px);
        let mut meta = SceneJson::new(
            self.cfg,
            self.layout,
            self.thermal_cam,
            self.effects,
            "images/thermal/",
            self.sensor.profile.netd_k,
        );
        meta.depth_units = "truth/depth/: camera z along the pixel-centre ray, millimetres, 0 = no \
                            surface";
        meta.temperature_units = "not written in the joint layout (no temperature/ folder): \
                                  apparent temperatures are in truth/apparent/ and truth/apparent_sr/";
        meta.joint = Some(joint_json(self.joint, &self.rig, self.rgb_cam, (w, h)));
        meta.truth_surface = Some(TruthSurfaceJson::new(
            surface_n,
            surface_camera(&self.thermal_cam)?,
            SURFACE_WHAT_JOINT,
        ));
        Ok(meta)
    }
}

/// The dataset's index, gathered instant by instant: the COLMAP images, the thermal poses
/// (for the surface truth) and `holdout.txt`.
struct JointIndex {
    records: Vec<ColmapImage>,
    thermal_poses: Vec<Rigid3>,
    holdout: String,
}

impl JointIndex {
    /// An empty index for `views` instants.
    fn with_capacity(views: usize) -> Self {
        Self {
            records: Vec::with_capacity(2 * views),
            thermal_poses: Vec::with_capacity(views),
            holdout: String::new(),
        }
    }

    /// Adds instant `k`: image `2k+1` (thermal) and `2k+2` (RGB), held out when
    /// k % [`HOLDOUT_EVERY`] == 0.
    fn add(
        &mut self,
        k: usize,
        thermal_name: String,
        rgb_name: String,
        thermal_from_world: Rigid3,
        rgb_from_world: &Rigid3,
    ) -> Result<(), SimError> {
        if k.is_multiple_of(HOLDOUT_EVERY) {
            self.holdout
                .push_str(&format!("{thermal_name}\n{rgb_name}\n"));
        }
        self.thermal_poses.push(thermal_from_world);
        self.records.push(colmap_image(
            2 * k + 1,
            THERMAL_CAMERA_ID,
            thermal_name,
            &thermal_from_world,
        )?);
        self.records.push(colmap_image(
            2 * k + 2,
            RGB_CAMERA_ID,
            rgb_name,
            rgb_from_world,
        )?);
        Ok(())
    }

    /// Writes `sparse/0` (both cameras, the images, surface points) and `holdout.txt`;
    /// returns the thermal poses.
    fn write(
        self,
        cfg: &SceneConfig,
        layout: SceneLayout,
        thermal_cam: CameraModel,
        rgb_cam: CameraModel,
    ) -> Result<Vec<Rigid3>, SimError> {
        let out = &cfg.out_dir;
        // Points from their own stream: the same for any image size or exposure.
        let mut points_rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x9017_5EED);
        let points = sample_surface_points(layout, 2000, &mut points_rng);
        write_colmap_text(
            &out.join("sparse/0"),
            &[(THERMAL_CAMERA_ID, thermal_cam), (RGB_CAMERA_ID, rgb_cam)],
            self.records,
            &points,
        )?;
        let p = out.join("holdout.txt");
        std::fs::write(&p, self.holdout).map_err(io(&p, "write"))?;
        Ok(self.thermal_poses)
    }
}

/// The `joint` object of `scene.json`: the RGB camera, the rig and the truth folders.
fn joint_json(
    joint: &JointOptions,
    rig: &Rigid3,
    rgb_cam: CameraModel,
    (w, h): (u32, u32),
) -> JointJson {
    let (rw, rh) = (rgb_cam.width_px, rgb_cam.height_px);
    let profile = RgbProfile::hd720();
    let q = rig.rotation;
    let t = rig.translation_m;
    let folder = |pose, (width_px, height_px), units, what| TruthFolder {
        pose,
        width_px,
        height_px,
        units,
        what,
    };
    let truth = BTreeMap::from([
        (
            "truth/apparent/thermal/",
            folder(
                "thermal",
                (w, h),
                "centikelvin, 16-bit",
                "apparent (black-body) temperature of the area-averaged in-band radiance at \
                 the thermal camera: no PSF blur, no noise, no response effects",
            ),
        ),
        (
            "truth/apparent_sr/thermal/",
            folder(
                "thermal",
                (rw, rh),
                "centikelvin, 16-bit",
                "the same at the thermal pose rendered with the RGB-sized camera (rgb_camera's \
                 intrinsics): the super-resolved truth of a thermal render at rgb_scale",
            ),
        ),
        (
            "truth/depth/thermal/",
            folder(
                "thermal",
                (w, h),
                "millimetres, 16-bit, 0 = no surface",
                "camera z along the pixel-centre ray",
            ),
        ),
        (
            "truth/depth/rgb/",
            folder(
                "rgb",
                (rw, rh),
                "millimetres, 16-bit, 0 = no surface",
                "camera z along the pixel-centre ray",
            ),
        ),
        (
            "truth/rgb/rgb/",
            folder(
                "rgb",
                (rw, rh),
                "8-bit sRGB",
                "the RGB input without blur or shot/read noise, at the input's exposure",
            ),
        ),
    ]);
    JointJson {
        rgb_scale: joint.rgb_scale,
        rgb_exposure: joint.rgb_exposure(),
        low_light: joint.low_light,
        rgb_full_well_e: profile.full_well_e,
        rgb_read_noise_e: profile.read_noise_e,
        thermal_from_rgb: JointTransform {
            rotation_wxyz: [q.w, q.x, q.y, q.z],
            translation_m: [t.x, t.y, t.z],
            meaning: "X_thermal = R X_rgb + t (the thermal camera 3 cm along the RGB camera's \
                      -x); thermal cam_from_world = thermal_from_rgb * rgb cam_from_world",
        },
        rgb_camera: rgb_cam,
        thermal_camera_id: THERMAL_CAMERA_ID,
        rgb_camera_id: RGB_CAMERA_ID,
        images: "instant k: COLMAP image 2k+1 images/thermal/NNNN.png (camera 1, the thermal \
                 pose) and image 2k+2 images/rgb/NNNN.png (camera 2, the RGB pose)",
        holdout: "holdout.txt: both images of every instant k with k % 8 == 0",
        truth,
    }
}
