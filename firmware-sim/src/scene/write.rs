//! Writing the thermal scene datasets (the `Objects` and `Wall` layouts without RGB camera):
//! per view the thermal image, RGB, depth and temperature truth, then the COLMAP model, the
//! truth surface, the response effects' files and `scene.json` (files in
//! firmware-sim/README.md, `scene`).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::cameras::{poses, scene_camera};
use super::files::{
    centikelvin_words, colmap_image, create_dirs, depth_mm_words, save_exported, save_rgb8,
    save_u16, write_colmap_text, write_json, write_response_files,
};
use super::meta::SceneJson;
use super::objects::sample_surface_points;
use super::render::render_scene;
use super::response::{ResponseEffects, ResponseSimulator};
use super::sensing::{expose_scene_rgb, scene_thermal_profile, sense_thermal};
use super::truth::{
    SURFACE_TRUTH_FILE, SURFACE_WHAT_DEFAULT, TruthSurfaceJson, surface_camera,
    write_surface_truth_with,
};
use super::{SceneConfig, SceneLayout, check_scene_config};
use crate::error::SimError;
use crate::physics::Radiometry;
use crate::render::RayGrid;
use crate::sensor::{RgbProfile, ThermalSensor};

/// Writes the `Objects` scene dataset (files in firmware-sim/README.md).
pub fn write_scene_set(
    cfg: &SceneConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(), SimError> {
    write_scene_set_with_layout(cfg, SceneLayout::Objects, progress)
}

/// Writes the scene dataset of `layout` (files in firmware-sim/README.md).
// The layout is an argument rather than a `SceneConfig` field so that `SceneConfig` literals
// elsewhere (firmware-sim/tests/scene_set.rs) keep compiling unchanged.
pub fn write_scene_set_with_layout(
    cfg: &SceneConfig,
    layout: SceneLayout,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(), SimError> {
    write_scene_set_with(cfg, layout, ResponseEffects::default(), progress)
}

/// Writes the scene dataset of `layout` with per-frame response `effects` (automatic gain
/// control on 8-bit exports, offset drift between flat-field corrections; truth in
/// `response.json`, see [`super::response`]). The joint RGB + thermal layout has its own
/// writer (module docs of [`super`]).
pub fn write_scene_set_with(
    cfg: &SceneConfig,
    layout: SceneLayout,
    effects: ResponseEffects,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(), SimError> {
    check_scene_config(cfg)?;
    let out = &cfg.out_dir;
    create_dirs(
        out,
        &["sparse/0", "images", "rgb", "depth", "temperature", "truth"],
    )?;
    let cam = scene_camera(cfg.width_px, cfg.height_px);
    let grid = RayGrid::new(&cam);
    let mut sensor = ThermalSensor::new(scene_thermal_profile(cam), cfg.seed);
    let radiometry = Radiometry::new();
    let rgb_profile = RgbProfile {
        camera: cam,
        ..RgbProfile::hd720()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5C3E);
    let mut response = ResponseSimulator::new(effects, cfg.seed);
    let poses = poses(layout, cfg.views);
    let (w, h) = (cfg.width_px, cfg.height_px);
    let mut images = Vec::with_capacity(cfg.views);
    for (k, cam_from_world) in poses.iter().enumerate() {
        let r = render_scene(layout, &grid, cam_from_world, &radiometry);
        let words = sense_thermal(&mut sensor, &r.radiance, w, h)?;
        let name = format!("{k:04}.png");
        let exported = response.export(&name, &words);
        save_exported(&out.join("images").join(&name), w, h, exported)?;
        save_u16(
            &out.join("depth").join(&name),
            w,
            h,
            depth_mm_words(&r.depth_m),
        )?;
        let temp = centikelvin_words(&r.temp_k);
        save_u16(&out.join("temperature").join(&name), w, h, temp)?;
        // RGB: the same pixels.
        let rgb = expose_scene_rgb(&rgb_profile, &r, w, h, &mut rng);
        save_rgb8(&out.join("rgb").join(&name), w, h, rgb)?;
        images.push(colmap_image(k + 1, 1, name, cam_from_world)?);
        progress(k + 1, cfg.views);
    }
    let points = sample_surface_points(layout, 2000, &mut rng);
    write_colmap_text(&out.join("sparse/0"), &[(1, cam)], images, &points)?;
    // The visible surface of every view (training and held-out), for scoring meshes.
    let surface_n = write_surface_truth_with(
        &out.join(SURFACE_TRUTH_FILE),
        layout,
        &cam,
        &poses,
        &radiometry,
    )?;
    let mut meta = SceneJson::new(cfg, layout, cam, effects, "images/", sensor.profile.netd_k);
    meta.truth_surface = Some(TruthSurfaceJson::new(
        surface_n,
        surface_camera(&cam)?,
        SURFACE_WHAT_DEFAULT,
    ));
    write_response_files(out, effects, &response)?;
    write_json(&out.join("scene.json"), &meta, "scene.json")
}
