//! The sensors of the scene datasets: the thermal core's profile and one noisy thermal frame
//! of a render ([`sense_thermal`]), and the RGB exposure of a render ([`expose_scene_rgb`]).

use rand_chacha::ChaCha8Rng;
use s3tir_calib::CameraModel;

use super::render::SceneRender;
use crate::error::SimError;
use crate::render::gaussian_blur;
use crate::sensor::{
    RgbProfile, ThermalOutput, ThermalProfile, ThermalSensor, expose_rgb_channels,
};

/// The thermal core of the scene datasets: the Lepton 3.5's noise and PSF at `camera`, without
/// telemetry, dropped frames, automatic flat-field corrections or fixed-pattern drift.
pub(crate) fn scene_thermal_profile(camera: CameraModel) -> ThermalProfile {
    let mut profile = ThermalProfile::lepton35();
    profile.camera = camera;
    profile.telemetry_rows = 0;
    profile.drop_probability = 0.0;
    profile.auto_ffc_period_s = 0.0;
    profile.fpn_drift_k_per_s = 0.0;
    profile
}

/// One thermal frame of a `w × h` area-averaged radiance image: PSF blur, then the sensor's
/// noise and TLinear output (centikelvin words).
pub(crate) fn sense_thermal(
    sensor: &mut ThermalSensor,
    radiance: &[f64],
    w: u32,
    h: u32,
) -> Result<Vec<u16>, SimError> {
    let blurred = gaussian_blur(
        radiance,
        w as usize,
        h as usize,
        sensor.profile.psf_sigma_px,
    );
    match sensor.next_frame(&blurred) {
        ThermalOutput::Frame(f) => Ok(f.words),
        ThermalOutput::Dropped { .. } => Err(SimError::InvalidParameter {
            parameter: "drop_probability",
            value: "0".into(),
            why: "a frame was dropped although dropping is disabled",
        }),
    }
}

/// RGB blur of the scene datasets, 1σ pixels.
pub(crate) const SCENE_RGB_BLUR_PX: f64 = 0.5;

/// The RGB image of a `w × h` render: the linear channels blurred by [`SCENE_RGB_BLUR_PX`],
/// exposed with shot and read noise, packed 8-bit sRGB.
pub(crate) fn expose_scene_rgb(
    profile: &RgbProfile,
    r: &SceneRender,
    w: u32,
    h: u32,
    rng: &mut ChaCha8Rng,
) -> Vec<u8> {
    let [c0, c1, c2] = r
        .rgb_linear
        .each_ref()
        .map(|c| gaussian_blur(c, w as usize, h as usize, SCENE_RGB_BLUR_PX));
    expose_rgb_channels(profile, [&c0, &c1, &c2], rng)
}
