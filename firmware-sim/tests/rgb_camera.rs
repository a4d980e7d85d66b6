//! Proves: the RGB camera's outputs are well-formed — YUYV has 2 bytes per pixel and the right
//! luma for grey levels, MJPEG decodes back to the image within JPEG error, low light is
//! darker and noisier; and the per-pixel ray interpolation every renderer relies on stays
//! within 0.005 px of the exact (Newton-inverted) distortion model for all three profiles.
//! Does not prove colour accuracy against a real sensor.
#![allow(clippy::unwrap_used)]

use glam::DVec2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use s3tir_firmware_sim::render::RayGrid;
use s3tir_firmware_sim::sensor::{
    RgbProfile, ThermalProfile, expose_rgb, rgb_to_jpeg, rgb_to_yuyv,
};

#[test]
fn yuyv_and_mjpeg_encode_the_exposed_image() {
    let (w, h) = (64usize, 32usize);
    let rgb: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let v = ((i % w) * 4) as u8;
            [v, v, v]
        })
        .collect();
    let yuyv = rgb_to_yuyv(&rgb, w, h);
    assert_eq!(yuyv.len(), w * h * 2);
    // Grey: U = V = 128, Y = 16 + 219/255 · v.
    for (k, px) in yuyv.chunks_exact(4).take(w / 2).enumerate() {
        let v = f64::from((k * 2 * 4) as u8);
        assert!(
            (f64::from(px[0]) - (16.0 + 0.859 * v)).abs() <= 1.0,
            "Y at {k}: {}",
            px[0]
        );
        assert!(
            (i32::from(px[1]) - 128).abs() <= 1 && (i32::from(px[3]) - 128).abs() <= 1,
            "chroma of grey"
        );
    }
    let jpeg = rgb_to_jpeg(&rgb, w as u32, h as u32).unwrap();
    assert_eq!(&jpeg[..2], &[0xFF, 0xD8], "JPEG SOI");
    let back = image::load_from_memory(&jpeg).unwrap().to_rgb8();
    let err: f64 = back
        .as_raw()
        .iter()
        .zip(&rgb)
        .map(|(a, b)| (f64::from(*a) - f64::from(*b)).abs())
        .sum::<f64>()
        / rgb.len() as f64;
    assert!(err < 3.0, "mean JPEG error {err} codes");
}

#[test]
fn low_light_is_darker_and_noisier() {
    let flat = vec![0.5; 4096];
    let stats = |p: &RgbProfile| {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let out = expose_rgb(p, &flat, [1.0, 1.0, 1.0], &mut rng);
        let v: Vec<f64> = out.iter().map(|&b| f64::from(b)).collect();
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        (m, sd / m)
    };
    let (m_day, cv_day) = stats(&RgbProfile::hd720());
    let (m_low, cv_low) = stats(&RgbProfile::hd720_low_light());
    assert!(m_low < 0.4 * m_day, "low light mean {m_low} vs {m_day}");
    assert!(
        cv_low > 3.0 * cv_day,
        "relative noise low light {cv_low} vs day {cv_day}"
    );
}

#[test]
fn interpolated_pixel_rays_match_the_exact_model() {
    for cam in [
        ThermalProfile::lepton35().camera,
        ThermalProfile::boson640().camera,
        RgbProfile::hd720().camera,
    ] {
        let grid = RayGrid::new(&cam);
        let mut worst: f64 = 0.0;
        let step_u = (cam.width_px / 16).max(1) as usize;
        let step_v = (cam.height_px / 12).max(1) as usize;
        for v in (0..cam.height_px as usize).step_by(step_v) {
            for u in (0..cam.width_px as usize).step_by(step_u) {
                for (a, b) in [(0.5, 0.5), (0.25, 0.75), (0.9, 0.1)] {
                    let ray = grid.sub_ray(u, v, a, b);
                    let px = cam.project(ray).unwrap();
                    let want = DVec2::new(u as f64 - 0.5 + a, v as f64 - 0.5 + b);
                    worst = worst.max((px - want).length());
                }
            }
        }
        assert!(
            worst < 0.005,
            "{}x{}: worst interpolation error {worst} px",
            cam.width_px,
            cam.height_px
        );
    }
}
