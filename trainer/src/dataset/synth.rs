//! A small analytic thermal scene written as a COLMAP dataset (`sparse/0/*.txt` +
//! `images/NNNN.png`, 16-bit TLinear centikelvin), for the trainer's tests and for `make demo`
//! when the simulated rig's `s3tir-firmware-sim scene` is not available.
//!
//! The scene (world frame: x right, y down, z forward; metres) is one wall, the plane
//! `z = WALL_Z_M`, seen by every camera:
//! - its left half (`x < 0`) is painted (ε ≈ 0.95) and its right half bare metal, so the
//!   apparent temperature steps from [`WALL_LEFT_K`] to [`WALL_RIGHT_K`] across the line
//!   `x = 0`: a **sharp emissivity edge**;
//! - a heated pipe runs horizontally behind the plaster at `y = PIPE_Y_M`, hottest at
//!   `x = PIPE_X_M` (where its hot water enters): its heat reaches the surface as a **smooth**
//!   bump `PIPE_PEAK_K · exp(−((y − PIPE_Y_M)/PIPE_SIGMA_M)² − ((x − PIPE_X_M)/PIPE_LENGTH_M)²)`
//!   added to the wall temperature (the usual look of an embedded pipe in a thermal
//!   inspection). It has no geometric or material edge: diffusion, the Gaussian's home ground.
//!
//! Each pixel is one point sample of its centre ray (as the trainer's renderer samples), no
//! noise: the data are exact, so errors measure the model, not the sensor.

use std::fs;
use std::path::Path;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_calib::{BrownConrady, CameraModel, Intrinsics};

use super::DatasetError;
use super::colmap::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, write_text_model};
use crate::camera::PinholeCamera;

pub const WALL_Z_M: f64 = 2.0;
pub const WALL_LEFT_K: f64 = 296.0;
pub const WALL_RIGHT_K: f64 = 306.0;
pub const PIPE_Y_M: f64 = 0.45;
pub const PIPE_SIGMA_M: f64 = 0.25;
pub const PIPE_PEAK_K: f64 = 14.0;
pub const PIPE_X_M: f64 = -0.45;
pub const PIPE_LENGTH_M: f64 = 0.5;

/// The surface point a ray meets and its temperature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub point: [f64; 3],
    pub temp_k: f64,
}

impl Hit {
    /// Within `tol_m` of the emissivity edge (`x = 0`).
    pub fn near_edge(&self, tol_m: f64) -> bool {
        self.point[0].abs() < tol_m
    }
    /// On the warm part of the pipe (within half a σ of its axis and of its hottest point).
    pub fn on_pipe(&self) -> bool {
        (self.point[1] - PIPE_Y_M).abs() < 0.5 * PIPE_SIGMA_M
            && (self.point[0] - PIPE_X_M).abs() < 0.5 * PIPE_LENGTH_M
    }
}

/// Apparent temperature of the wall point `(x, y)`.
pub fn wall_temp_k(x: f64, y: f64) -> f64 {
    let base = if x < 0.0 { WALL_LEFT_K } else { WALL_RIGHT_K };
    let ry = (y - PIPE_Y_M) / PIPE_SIGMA_M;
    let rx = (x - PIPE_X_M) / PIPE_LENGTH_M;
    base + PIPE_PEAK_K * (-ry * ry - rx * rx).exp()
}

/// First surface along `origin + t·dir`, `t > 0`.
pub fn trace(origin: DVec3, dir: DVec3) -> Option<Hit> {
    if dir.z.abs() > 1e-12 {
        let t = (WALL_Z_M - origin.z) / dir.z;
        if t > 0.0 {
            let p = origin + t * dir;
            return Some(Hit {
                point: p.to_array(),
                temp_k: wall_temp_k(p.x, p.y),
            });
        }
    }
    None
}

/// Parameters of the synthetic scene.
#[derive(Debug, Clone)]
pub struct SynthConfig {
    pub views: usize,
    pub width: usize,
    pub height: usize,
    pub f_px: f64,
    /// Sparse points written to `points3D.txt` (0: none, the loader then initialises at random).
    pub points: usize,
    pub seed: u64,
}

impl SynthConfig {
    /// The benchmarks' scene (`s3tir-train bench`, `bench --mesh`): `views` of
    /// `width × height` with a 0.85·width focal length and `points` sparse points (the
    /// primitives a run initialises).
    pub fn bench(width: usize, height: usize, views: usize, points: usize) -> Self {
        Self {
            views,
            width,
            height,
            f_px: 0.85 * width as f64,
            points,
            ..Self::default()
        }
    }
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            views: 16,
            width: 48,
            height: 36,
            f_px: 40.0,
            points: 400,
            seed: 7,
        }
    }
}

/// The cameras of the scene: a 4-wide grid of eyes on the plane z = 0 looking at the wall.
pub fn cameras(cfg: &SynthConfig) -> Vec<PinholeCamera> {
    (0..cfg.views)
        .map(|i| {
            let col = (i % 4) as f64;
            let row = (i / 4) as f64;
            let rows = cfg.views.div_ceil(4).max(1) as f64;
            let eye = [
                -0.36 + 0.24 * col,
                -0.2 + 0.4 * row / (rows - 1.0).max(1.0),
                0.0,
            ];
            let target = [0.1 * (col - 1.5) / 1.5, 0.1, WALL_Z_M];
            PinholeCamera::look_at(
                eye,
                target,
                [0.0, -1.0, 0.0],
                cfg.f_px,
                cfg.width,
                cfg.height,
            )
        })
        .collect()
}

/// Renders the ground-truth temperature (kelvin) and the hit surface of every pixel.
pub fn render_truth(cam: &PinholeCamera) -> Vec<Option<Hit>> {
    let world_from_cam = cam.cam_from_world.inverse();
    let origin = world_from_cam.translation_m;
    let mut out = Vec::with_capacity(cam.width * cam.height);
    for v in 0..cam.height {
        for u in 0..cam.width {
            let d_cam = DVec3::new(
                (u as f64 - cam.cx_px) / cam.fx_px,
                (v as f64 - cam.cy_px) / cam.fy_px,
                1.0,
            );
            out.push(trace(origin, world_from_cam.transform_vector(d_cam)));
        }
    }
    out
}

/// Writes the dataset into `out_dir` (`sparse/0/` + `images/`). Returns the cameras.
pub fn write_scene(out_dir: &Path, cfg: &SynthConfig) -> Result<Vec<PinholeCamera>, DatasetError> {
    let cams = cameras(cfg);
    let images_dir = out_dir.join("images");
    fs::create_dir_all(&images_dir).map_err(|e| DatasetError::Io {
        path: images_dir.clone(),
        source: e,
    })?;
    let mut model = ColmapModel::default();
    model.cameras.push(ColmapCamera {
        id: 1,
        model_name: "PINHOLE".into(),
        model: CameraModel {
            width_px: cfg.width as u32,
            height_px: cfg.height as u32,
            intrinsics: Intrinsics {
                fx: cfg.f_px,
                fy: cfg.f_px,
                cx: (cfg.width as f64 - 1.0) / 2.0,
                cy: (cfg.height as f64 - 1.0) / 2.0,
            },
            distortion: BrownConrady::default(),
        },
    });
    for (i, cam) in cams.iter().enumerate() {
        let truth = render_truth(cam);
        let words: Vec<u16> = truth
            .iter()
            .map(|h| {
                let k = h.map_or(WALL_LEFT_K, |h| h.temp_k);
                (k * 100.0).round().clamp(0.0, 65535.0) as u16
            })
            .collect();
        let name = format!("{i:04}.png");
        let path = images_dir.join(&name);
        let buf = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
            cfg.width as u32,
            cfg.height as u32,
            words,
        )
        .ok_or_else(|| DatasetError::UnsupportedImage {
            path: path.clone(),
            reason: "buffer size mismatch".into(),
        })?;
        buf.save(&path).map_err(|source| DatasetError::Image {
            path: path.clone(),
            source,
        })?;
        model.images.push(ColmapImage {
            id: i as u32 + 1,
            camera_id: 1,
            name,
            cam_from_world: cam.cam_from_world,
        });
    }
    // Sparse points: seeded samples of the surfaces seen by the cameras (as SfM would give).
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut id = 1u64;
    let mut tries = 0;
    while (id as usize) <= cfg.points && tries < cfg.points * 100 {
        tries += 1;
        let cam = &cams[rng.random_range(0..cams.len())];
        let u = rng.random_range(0.0..cfg.width as f64 - 1.0);
        let v = rng.random_range(0.0..cfg.height as f64 - 1.0);
        let world_from_cam = cam.cam_from_world.inverse();
        let d = world_from_cam.transform_vector(DVec3::new(
            (u - cam.cx_px) / cam.fx_px,
            (v - cam.cy_px) / cam.fy_px,
            1.0,
        ));
        if let Some(hit) = trace(world_from_cam.translation_m, d) {
            let grey = (((hit.temp_k - 290.0) / 40.0).clamp(0.0, 1.0) * 255.0) as u8;
            model.points.push(ColmapPoint {
                id,
                position_m: hit.point,
                rgb: [grey; 3],
            });
            id += 1;
        }
    }
    write_text_model(&out_dir.join("sparse").join("0"), &model)?;
    Ok(cams)
}
