//! Simple thermal scenes with ground truth for the trainer, written as a COLMAP text model.
//! Two layouts ([`SceneLayout`]): `Objects` (the default, below) and `Wall` (further below).
//! The same scenes seen by a thermal + RGB rig, RGB at K× the thermal resolution, with
//! high-resolution truth: [`crate::scene_joint`] (`scene --rgb-scale K`).
//!
//! Truth written beside the images: `depth/` and `temperature/` per view (camera z and true
//! surface temperature along each pixel-centre ray) and `truth/surface.ply`, the visible
//! surface of the whole set with its apparent temperature, for scoring meshes
//! ([`crate::scene_truth`]: the pixel-centre hits of the thermal camera at 2× its resolution
//! from every view, one point per 4 mm cube, first in view order then row-major; kelvin is
//! the apparent temperature at emissivity 1, view-independent since every surface is a grey
//! body reflecting the uniform [`ENV_K`]).
//!
//! World frame: x east, y north, z up, metres; the ground is the plane z = 0.
//!
//! ## `Objects` layout
//!
//! Objects (all grey bodies reflecting surroundings at [`ENV_K`]):
//! - ground plane, |x|, |y| ≤ 2 m, 291 K, ε 0.95 (RGB: two-tone 0.2 m tiles), with an
//!   underfloor heating pipe along y at x = 0.7 m whose heat reaches the floor surface by
//!   conduction as a smooth warm stripe, 291 K + 9 K·exp(−((x − 0.7 m)/0.12 m)²) (no edge of any
//!   kind: diffusion);
//! - heated pipe: cylinder along x from −0.6 to 0.6 m, radius 15 cm (an insulated heating
//!   main), axis at y = 0.3 m, z = 0.3 m (15 cm clear of the ground), ε 0.9, temperature falling
//!   linearly from 333 K (x = −0.6) to 303 K (x = 0.6): apparent temperature smooth across its
//!   surface (constant ε), so its interior, ~10 px wide at 64 px image width, is a smooth region
//!   and only its outline is an edge;
//! - box 0.3 m cube centred at (0, −0.35, 0.15), 313 K everywhere, painted (ε 0.95) for x < 0,
//!   bare metal (ε 0.12) for x ≥ 0: a sharp apparent-temperature edge on a uniform temperature;
//! - radiator panel: vertical rectangle x = −0.9 m, y ∈ [−0.45, 0.45], z ∈ [0.05, 0.65], fins
//!   every 6 cm (318 ± 4 K), ε 0.93.
//!
//! Rays that hit nothing see a background at [`BACKGROUND_K`] (black body).
//!
//! Cameras: pinhole without distortion (COLMAP `PINHOLE`), on an orbit of radius 1.6 m at
//! height 0.9 m around (0, 0, 0.15), all looking at that point, the first at azimuth
//! π/2 + 0.1 rad (near the +y axis: the pipe side-on); 57° horizontal field of view.
//!
//! ## `Wall` layout: a wall inspection (an in-wall heating pipe)
//!
//! One vertical wall, the plane y = [`WALL_Y`] (facing −y), x ∈ [`WALL_X`], z ∈ [`WALL_Z`]:
//! 6 m × 3 m, larger than any view of its camera set, so every pixel sees wall — no background,
//! no silhouette. A grey body reflecting [`ENV_K`] like every surface here:
//! - the cold exterior wall of a heated room in winter, seen from inside: [`WALL_BASE_K`] =
//!   280 K, 10 K below the 290 K room it reflects, so emissivity matters;
//! - painted (ε [`WALL_PAINT_EMISSIVITY`] = 0.95) for x < [`WALL_EDGE_X`] = 0 and bare metal
//!   (ε [`WALL_METAL_EMISSIVITY`] = 0.12) for x ≥ 0: the **sharp emissivity edge**, a vertical
//!   line; apparent temperature ≈ 280.5 K on the paint, ≈ 289 K on the metal (which mostly
//!   mirrors the room);
//! - a heating pipe inside the wall, horizontal at height [`WALL_PIPE_Z`] = 0.75 m, whose heat
//!   reaches the surface by conduction as a smooth warm band (no edge of any kind):
//!   `WALL_PIPE_PEAK_K · exp(−((z − 0.75 m)/0.2 m)²) · exp(−((x + 0.6 m)/1.0 m)²)`
//!   ([`WALL_PIPE_PEAK_K`] = 12 K, σ [`WALL_PIPE_SIGMA`] = 0.2 m across, hottest at
//!   x = [`WALL_PIPE_HOT_X`] = −0.6 m where its hot water enters, slowly cooling along x over
//!   [`WALL_PIPE_LENGTH`] = 1 m: [`wall_temp_k`]), the **smooth heated pipe**: up to ≈ 291.5 K
//!   apparent on the paint; behind the bare metal it barely shows (ε 0.12: the classic
//!   thermography pitfall).
//!
//! Why a cold wall rather than a heated one: with the trainer (`s3tir-train`, 400 iterations),
//! β drifts up on bright flat regions, and the data are normalised to the scene's range; at
//! 305 K the painted side, where the pipe shows, is the bright side (Ψ_β on the pipe band
//! 2.54, measured as in `tests/tests/train_fwsim.rs`), at 280 K the dark one (2.07).
//!
//! RGB: blue-grey paint, metal grey; the pipe is invisible in RGB.
//! Cameras ([`wall_arc`]): the same pinhole, on an arc of radius 1.6 m around the point
//! (0, 0, 0.95) of the edge line, yaw from −25° to +25° (view 0 at −25°, evenly spaced),
//! heights 0.95 m + (−0.15, 0, +0.15 m) in turn, all looking at that point: every view sees
//! both sides of the edge and the pipe's band, and every pair of views overlaps.

use rayon::prelude::*;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec2, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_calib::{BrownConrady, CameraModel, Intrinsics, Rigid3};
use serde::Serialize;

use crate::error::SimError;
use crate::physics::Radiometry;
use crate::render::{RayGrid, gaussian_blur};
use crate::response::{ExportedFrame, ResponseEffects, ResponseSimulator};
use crate::scene_truth::{
    SURFACE_TRUTH_FILE, SURFACE_WHAT_DEFAULT, TruthSurfaceJson, surface_camera,
    write_surface_truth_with,
};
use crate::sensor::{
    RgbProfile, ThermalOutput, ThermalProfile, ThermalSensor, expose_rgb_channels,
};

/// Temperature of the surroundings every surface reflects, kelvin.
pub const ENV_K: f64 = 290.0;
/// Apparent temperature of rays that hit nothing, kelvin.
pub const BACKGROUND_K: f64 = 285.0;
const BACKGROUND_RGB: [f64; 3] = [0.30, 0.34, 0.40];

/// Which scene [`write_scene_set_with_layout`] and friends render (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SceneLayout {
    /// Box, free-standing pipe, floor with an underfloor pipe, radiator, seen from an orbit.
    #[default]
    Objects,
    /// A wall with an emissivity edge and an in-wall heating pipe, filling every view.
    Wall,
}

/// Parameters of a scene dataset.
#[derive(Debug, Clone)]
pub struct SceneConfig {
    pub out_dir: PathBuf,
    pub views: usize,
    pub width_px: u32,
    pub height_px: u32,
    pub seed: u64,
}

/// What a ray hits.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceHit {
    /// Ray parameter: distance along the (unit-z) camera ray, i.e. depth if the ray has z = 1.
    pub t: f64,
    pub temp_k: f64,
    pub emissivity: f64,
    pub albedo: [f64; 3],
    /// Unit normal facing the ray origin (world frame).
    pub normal: DVec3,
    /// The object hit.
    pub object: SceneObject,
}

/// Which object a ray hit (ground truth for masks in tests and tools).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneObject {
    Ground,
    /// The pipe's cylindrical side.
    PipeSide,
    /// One of the pipe's two end caps.
    PipeCap,
    /// The box: painted (x < [`BOX_C`].x) or bare metal.
    Box,
    Radiator,
    /// The wall of the `Wall` layout: painted (x < [`WALL_EDGE_X`]) or bare metal.
    Wall,
}

/// Pipe extent along x, metres.
pub const PIPE_X: (f64, f64) = (-0.6, 0.6);
/// Pipe radius, metres.
pub const PIPE_R: f64 = 0.15;
/// Pipe axis (y, z), metres.
pub const PIPE_YZ: (f64, f64) = (0.3, 0.3);
/// Box centre, metres; the emissivity edge is the plane x = `BOX_C.x`.
pub const BOX_C: DVec3 = DVec3::new(0.0, -0.35, 0.15);
/// Box half-size, metres.
pub const BOX_H: f64 = 0.15;
/// Underfloor heating pipe: the floor's warm stripe is centred on x = `FLOOR_PIPE_X`, metres.
pub const FLOOR_PIPE_X: f64 = 0.7;
/// Width parameter σ of the warm stripe `exp(−((x − FLOOR_PIPE_X)/σ)²)`, metres.
pub const FLOOR_PIPE_SIGMA: f64 = 0.12;
/// Peak warming of the floor surface above the pipe, kelvin.
pub const FLOOR_PIPE_PEAK_K: f64 = 9.0;

/// Floor surface temperature at `x` (291 K plus the underfloor pipe's stripe).
pub fn floor_temp_k(x: f64) -> f64 {
    291.0 + FLOOR_PIPE_PEAK_K * (-((x - FLOOR_PIPE_X) / FLOOR_PIPE_SIGMA).powi(2)).exp()
}
/// Wall layout: the wall is the plane y = `WALL_Y`, metres.
pub const WALL_Y: f64 = 0.0;
/// Wall layout: the wall's extent along x, metres.
pub const WALL_X: (f64, f64) = (-3.0, 3.0);
/// Wall layout: the wall's extent along z, metres.
pub const WALL_Z: (f64, f64) = (0.0, 3.0);
/// Wall layout: temperature of the wall away from the pipe, kelvin.
pub const WALL_BASE_K: f64 = 280.0;
/// Wall layout: the emissivity edge is the vertical line x = `WALL_EDGE_X` (painted for x below).
pub const WALL_EDGE_X: f64 = 0.0;
/// Wall layout: emissivity of the painted part.
pub const WALL_PAINT_EMISSIVITY: f64 = 0.95;
/// Wall layout: emissivity of the bare-metal part.
pub const WALL_METAL_EMISSIVITY: f64 = 0.12;
/// Wall layout: height of the in-wall pipe's axis (the warm band's centre line), metres.
pub const WALL_PIPE_Z: f64 = 0.75;
/// Wall layout: width parameter σ of the warm band across the pipe, metres.
pub const WALL_PIPE_SIGMA: f64 = 0.2;
/// Wall layout: peak warming of the wall surface above the pipe, kelvin.
pub const WALL_PIPE_PEAK_K: f64 = 12.0;
/// Wall layout: where along x the pipe is hottest, metres.
pub const WALL_PIPE_HOT_X: f64 = -0.6;
/// Wall layout: length scale of the band's slow cooling along x, metres.
pub const WALL_PIPE_LENGTH: f64 = 1.0;

/// Wall surface temperature at `(x, z)`: [`WALL_BASE_K`] plus the in-wall pipe's warm band.
pub fn wall_temp_k(x: f64, z: f64) -> f64 {
    let across = (z - WALL_PIPE_Z) / WALL_PIPE_SIGMA;
    let along = (x - WALL_PIPE_HOT_X) / WALL_PIPE_LENGTH;
    WALL_BASE_K + WALL_PIPE_PEAK_K * (-across * across - along * along).exp()
}

/// Wall layout: emissivity and RGB albedo at `x`.
fn wall_material(x: f64) -> (f64, [f64; 3]) {
    if x < WALL_EDGE_X {
        (WALL_PAINT_EMISSIVITY, [0.30, 0.38, 0.55])
    } else {
        (WALL_METAL_EMISSIVITY, [0.62, 0.62, 0.64])
    }
}

// The radiator stands off the pipe's hot end (plane x = RAD_X, facing +x), clear of the lines
// of sight of the views from ±y that see the pipe side-on.
pub(crate) const RAD_X: f64 = -0.9;
pub(crate) const RAD_Y: (f64, f64) = (-0.45, 0.45);
pub(crate) const RAD_Z: (f64, f64) = (0.05, 0.65);

fn pipe_temp_k(x: f64) -> f64 {
    let f = ((x - PIPE_X.0) / (PIPE_X.1 - PIPE_X.0)).clamp(0.0, 1.0);
    333.0 - 30.0 * f
}

fn radiator_temp_k(y: f64) -> f64 {
    318.0 + 4.0 * (2.0 * std::f64::consts::PI * y / 0.06).cos()
}

fn face(n: DVec3, d: DVec3) -> DVec3 {
    if n.dot(d) > 0.0 { -n } else { n }
}

/// Nearest surface of `layout` along the ray `o + t d` (t > 1e-9), world frame.
pub fn trace(layout: SceneLayout, o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    match layout {
        SceneLayout::Objects => trace_objects(o, d),
        SceneLayout::Wall => trace_wall(o, d),
    }
}

fn trace_wall(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    if d.y.abs() <= 1e-12 {
        return None;
    }
    let t = (WALL_Y - o.y) / d.y;
    let p = o + d * t;
    let inside = p.x >= WALL_X.0 && p.x <= WALL_X.1 && p.z >= WALL_Z.0 && p.z <= WALL_Z.1;
    (t > 1e-9 && inside).then(|| {
        let (emissivity, albedo) = wall_material(p.x);
        SurfaceHit {
            t,
            temp_k: wall_temp_k(p.x, p.z),
            emissivity,
            albedo,
            normal: face(DVec3::Y, d),
            object: SceneObject::Wall,
        }
    })
}

fn trace_objects(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let mut best: Option<SurfaceHit> = None;
    let mut consider = |h: SurfaceHit| {
        if h.t > 1e-9 && best.is_none_or(|b| h.t < b.t) {
            best = Some(h);
        }
    };
    // Ground.
    if d.z.abs() > 1e-12 {
        let t = -o.z / d.z;
        let p = o + d * t;
        if p.x.abs() <= 2.0 && p.y.abs() <= 2.0 {
            let tile = ((p.x / 0.2).floor() + (p.y / 0.2).floor()) as i64 % 2 == 0;
            let a = if tile { 0.30 } else { 0.38 };
            consider(SurfaceHit {
                t,
                temp_k: floor_temp_k(p.x),
                emissivity: 0.95,
                albedo: [a, a * 0.95, a * 0.85],
                normal: face(DVec3::Z, d),
                object: SceneObject::Ground,
            });
        }
    }
    // Pipe side.
    let (oy, oz) = (o.y - PIPE_YZ.0, o.z - PIPE_YZ.1);
    let a = d.y * d.y + d.z * d.z;
    if a > 1e-15 {
        let b = 2.0 * (oy * d.y + oz * d.z);
        let c = oy * oy + oz * oz - PIPE_R * PIPE_R;
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            for t in [
                (-b - disc.sqrt()) / (2.0 * a),
                (-b + disc.sqrt()) / (2.0 * a),
            ] {
                let p = o + d * t;
                if t > 1e-9 && p.x >= PIPE_X.0 && p.x <= PIPE_X.1 {
                    let n = DVec3::new(0.0, p.y - PIPE_YZ.0, p.z - PIPE_YZ.1) / PIPE_R;
                    consider(SurfaceHit {
                        t,
                        temp_k: pipe_temp_k(p.x),
                        emissivity: 0.9,
                        albedo: [0.55, 0.25, 0.12],
                        normal: face(n, d),
                        object: SceneObject::PipeSide,
                    });
                    break;
                }
            }
        }
    }
    // Pipe end caps.
    if d.x.abs() > 1e-12 {
        for x in [PIPE_X.0, PIPE_X.1] {
            let t = (x - o.x) / d.x;
            let p = o + d * t;
            if (p.y - PIPE_YZ.0).powi(2) + (p.z - PIPE_YZ.1).powi(2) <= PIPE_R * PIPE_R {
                consider(SurfaceHit {
                    t,
                    temp_k: pipe_temp_k(x),
                    emissivity: 0.9,
                    albedo: [0.45, 0.2, 0.1],
                    normal: face(DVec3::X, d),
                    object: SceneObject::PipeCap,
                });
            }
        }
    }
    // Box (slabs).
    let lo = BOX_C - DVec3::splat(BOX_H);
    let hi = BOX_C + DVec3::splat(BOX_H);
    let (mut t0, mut t1, mut axis0) = (f64::MIN, f64::MAX, 0usize);
    let mut hit_box = true;
    for k in 0..3 {
        let (ok, dk, lk, hk) = (o[k], d[k], lo[k], hi[k]);
        if dk.abs() < 1e-15 {
            if ok < lk || ok > hk {
                hit_box = false;
            }
            continue;
        }
        let (mut a, mut b) = ((lk - ok) / dk, (hk - ok) / dk);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t0 {
            t0 = a;
            axis0 = k;
        }
        t1 = t1.min(b);
    }
    if hit_box && t0 <= t1 && t0 > 1e-9 {
        let p = o + d * t0;
        let mut n = DVec3::ZERO;
        n[axis0] = 1.0;
        let painted = p.x < BOX_C.x;
        consider(SurfaceHit {
            t: t0,
            temp_k: 313.0,
            emissivity: if painted { 0.95 } else { 0.12 },
            albedo: if painted {
                [0.15, 0.25, 0.6]
            } else {
                [0.6, 0.6, 0.62]
            },
            normal: face(n, d),
            object: SceneObject::Box,
        });
    }
    // Radiator panel (double-sided).
    if d.x.abs() > 1e-12 {
        let t = (RAD_X - o.x) / d.x;
        let p = o + d * t;
        if p.y >= RAD_Y.0 && p.y <= RAD_Y.1 && p.z >= RAD_Z.0 && p.z <= RAD_Z.1 {
            let fin = 0.75 + 0.1 * (2.0 * std::f64::consts::PI * p.y / 0.06).cos();
            consider(SurfaceHit {
                t,
                temp_k: radiator_temp_k(p.y),
                emissivity: 0.93,
                albedo: [fin, fin, fin * 0.97],
                normal: face(DVec3::X, d),
                object: SceneObject::Radiator,
            });
        }
    }
    best
}

/// `cam_from_world` of a camera at `eye` looking at `target` (world z up, image y down).
pub fn look_at(eye: DVec3, target: DVec3) -> Rigid3 {
    let fwd = (target - eye).normalize();
    let right = fwd.cross(DVec3::Z).normalize();
    let down = fwd.cross(right);
    let world_from_cam = Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(right, down, fwd)), eye);
    world_from_cam.inverse()
}

/// The orbit: `n` cameras evenly spaced in azimuth.
pub fn orbit(n: usize) -> Vec<Rigid3> {
    let target = DVec3::new(0.0, 0.0, 0.15);
    (0..n)
        .map(|k| {
            // View 0 sits near the +y axis (0.1 rad past it), so it and view n/2 (the trainer's
            // default hold-out of every 8th view, for n = 16) see the pipe from the side, the
            // box's emissivity edge face-on.
            let a = 2.0 * std::f64::consts::PI * k as f64 / n.max(1) as f64
                + std::f64::consts::FRAC_PI_2
                + 0.1;
            let eye = DVec3::new(1.6 * a.cos(), 1.6 * a.sin(), 0.9);
            look_at(eye, target)
        })
        .collect()
}

/// The wall layout's cameras: `n` poses on an arc in front of the wall (module docs).
pub fn wall_arc(n: usize) -> Vec<Rigid3> {
    let target = DVec3::new(WALL_EDGE_X, WALL_Y, 0.95);
    (0..n)
        .map(|k| {
            let f = if n > 1 {
                k as f64 / (n - 1) as f64
            } else {
                0.5
            };
            let yaw = (-25.0 + 50.0 * f).to_radians();
            let dz = 0.15 * ((k % 3) as f64 - 1.0);
            let eye = target + DVec3::new(1.6 * yaw.sin(), -1.6 * yaw.cos(), dz);
            look_at(eye, target)
        })
        .collect()
}

/// The `n` camera poses (`cam_from_world`) of `layout`: [`orbit`] or [`wall_arc`].
pub fn poses(layout: SceneLayout, n: usize) -> Vec<Rigid3> {
    match layout {
        SceneLayout::Objects => orbit(n),
        SceneLayout::Wall => wall_arc(n),
    }
}

/// The pinhole camera of a `width × height` scene image (57° horizontal field of view).
pub fn scene_camera(width_px: u32, height_px: u32) -> CameraModel {
    let f = f64::from(width_px) / 2.0 / (28.5f64.to_radians()).tan();
    CameraModel {
        width_px,
        height_px,
        intrinsics: Intrinsics {
            fx: f,
            fy: f,
            cx: (f64::from(width_px) - 1.0) / 2.0,
            cy: (f64::from(height_px) - 1.0) / 2.0,
        },
        distortion: BrownConrady::default(),
    }
}

/// Per-view renders.
#[derive(Debug, Clone)]
pub struct SceneRender {
    /// Area-averaged apparent in-band radiance (4×4 sub-samples per pixel).
    pub radiance: Vec<f64>,
    /// Area-averaged linear RGB (shaded albedo).
    pub rgb_linear: [Vec<f64>; 3],
    /// Depth (camera z, metres) along the pixel-centre ray; 0 where nothing is hit.
    pub depth_m: Vec<f64>,
    /// True surface temperature along the pixel-centre ray, kelvin; 0 where nothing is hit.
    pub temp_k: Vec<f64>,
}

/// Sub-samples per pixel axis.
pub const SCENE_SUBPIXELS: usize = 4;

/// Renders one view of the scene `layout`.
pub fn render_scene(
    layout: SceneLayout,
    grid: &RayGrid,
    cam_from_world: &Rigid3,
    radiometry: &Radiometry,
) -> SceneRender {
    let (w, h) = (grid.width(), grid.height());
    let world_from_cam = cam_from_world.inverse();
    let eye = world_from_cam.translation_m;
    let light = DVec3::new(0.3, -0.4, 1.0).normalize();
    let l_env = radiometry.radiance(ENV_K);
    let l_bg = radiometry.radiance(BACKGROUND_K);
    let n = SCENE_SUBPIXELS;
    // Per pixel: radiance, linear RGB, depth, temperature. Rows in parallel; each pixel is
    // computed as alone, so the render does not depend on the thread count.
    let mut px = vec![[0.0f64; 6]; w * h];
    if w > 0 {
        px.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, out) in row.iter_mut().enumerate() {
                let (mut l_acc, mut c_acc) = (0.0, [0.0; 3]);
                for j in 0..n {
                    for i in 0..n {
                        let ray = grid.sub_ray(
                            u,
                            v,
                            (i as f64 + 0.5) / n as f64,
                            (j as f64 + 0.5) / n as f64,
                        );
                        let d = world_from_cam.transform_vector(ray);
                        match trace(layout, eye, d) {
                            Some(s) => {
                                l_acc += s.emissivity * radiometry.radiance(s.temp_k)
                                    + (1.0 - s.emissivity) * l_env;
                                let shade = 0.35 + 0.65 * s.normal.dot(light).max(0.0);
                                for (c, a) in c_acc.iter_mut().zip(s.albedo) {
                                    *c += a * shade;
                                }
                            }
                            None => {
                                l_acc += l_bg;
                                for (c, a) in c_acc.iter_mut().zip(BACKGROUND_RGB) {
                                    *c += a;
                                }
                            }
                        }
                    }
                }
                let nn = (n * n) as f64;
                out[0] = l_acc / nn;
                for (o, c) in out[1..4].iter_mut().zip(c_acc) {
                    *o = c / nn;
                }
                let centre = grid.centre_ray(u, v);
                if let Some(s) = trace(layout, eye, world_from_cam.transform_vector(centre)) {
                    // The ray has camera z = 1, so t is the depth.
                    out[4] = s.t;
                    out[5] = s.temp_k;
                }
            }
        });
    }
    let plane = |k: usize| px.iter().map(|p| p[k]).collect::<Vec<f64>>();
    SceneRender {
        radiance: plane(0),
        rgb_linear: [plane(1), plane(2), plane(3)],
        depth_m: plane(4),
        temp_k: plane(5),
    }
}

fn albedo_to_srgb8(a: [f64; 3]) -> [u8; 3] {
    a.map(|c| (crate::sensor::srgb_encode(c) * 255.0).round() as u8)
}

/// `count` points sampled on the surfaces of `layout` (Objects: the objects and the near
/// ground; Wall: the part of the wall the cameras see, x ∈ ±1.5 m, z ∈ [0.1, 1.8] m), with
/// colour.
pub fn sample_surface_points(
    layout: SceneLayout,
    count: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<(DVec3, [u8; 3])> {
    match layout {
        SceneLayout::Objects => sample_object_points(count, rng),
        SceneLayout::Wall => (0..count)
            .map(|_| {
                let x = rng.random_range(-1.5..1.5);
                let z = rng.random_range(0.1..1.8);
                (
                    DVec3::new(x, WALL_Y, z),
                    albedo_to_srgb8(wall_material(x).1),
                )
            })
            .collect(),
    }
}

fn sample_object_points(count: usize, rng: &mut ChaCha8Rng) -> Vec<(DVec3, [u8; 3])> {
    let mut pts = Vec::with_capacity(count);
    let to8 = albedo_to_srgb8;
    while pts.len() < count {
        let kind = rng.random_range(0..4);
        let (p, albedo) = match kind {
            0 => {
                let p = DVec3::new(
                    rng.random_range(-1.2..1.2),
                    rng.random_range(-1.2..1.2),
                    0.0,
                );
                let h = trace_objects(p + DVec3::Z * 1e-3, DVec3::NEG_Z);
                (p, h.map_or([0.3; 3], |h| h.albedo))
            }
            1 => {
                let x = rng.random_range(PIPE_X.0..PIPE_X.1);
                let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                (
                    DVec3::new(
                        x,
                        PIPE_YZ.0 + PIPE_R * a.cos(),
                        PIPE_YZ.1 + PIPE_R * a.sin(),
                    ),
                    [0.55, 0.25, 0.12],
                )
            }
            2 => {
                // A point on one of the five visible box faces (not the bottom).
                let f = rng.random_range(0..5usize);
                let (s, t): (f64, f64) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                let local = match f {
                    0 => DVec3::new(1.0, s, t),
                    1 => DVec3::new(-1.0, s, t),
                    2 => DVec3::new(s, 1.0, t),
                    3 => DVec3::new(s, -1.0, t),
                    _ => DVec3::new(s, t, 1.0),
                };
                let p = BOX_C + local * BOX_H;
                (
                    p,
                    if p.x < BOX_C.x {
                        [0.15, 0.25, 0.6]
                    } else {
                        [0.6, 0.6, 0.62]
                    },
                )
            }
            _ => {
                let p = DVec3::new(
                    RAD_X,
                    rng.random_range(RAD_Y.0..RAD_Y.1),
                    rng.random_range(RAD_Z.0..RAD_Z.1),
                );
                (p, [0.75; 3])
            }
        };
        pts.push((p, to8(albedo)));
    }
    pts
}

/// `scene.json` (firmware-sim/README.md, `scene`); the joint layout adds `joint`
/// ([`crate::scene_joint`]).
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
    pub(crate) joint: Option<crate::scene_joint::JointJson>,
    /// `truth/surface.ply` ([`crate::scene_truth`]): both writers set it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) truth_surface: Option<crate::scene_truth::TruthSurfaceJson>,
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
            layout: match layout {
                SceneLayout::Objects => "objects",
                SceneLayout::Wall => "wall",
            },
            world_frame: match layout {
                SceneLayout::Objects => "x east, y north, z up, metres; ground plane z = 0",
                SceneLayout::Wall => "x east, y north, z up, metres; wall plane y = 0, facing -y",
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

/// The error of a failed file operation `what` on `path`.
pub(crate) fn io(path: &Path, what: &'static str) -> impl FnOnce(std::io::Error) -> SimError {
    let path = path.to_path_buf();
    move |source| SimError::Io { path, what, source }
}

/// Creates the folders `dirs` (relative to `out`) and their parents.
pub(crate) fn create_dirs(out: &Path, dirs: &[&str]) -> Result<(), SimError> {
    for d in dirs {
        let p = out.join(d);
        fs::create_dir_all(&p).map_err(io(&p, "create directory"))?;
    }
    Ok(())
}

/// Writes a `w × h` 16-bit grey PNG.
pub(crate) fn save_u16(path: &Path, w: u32, h: u32, data: Vec<u16>) -> Result<(), SimError> {
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, data).ok_or(
        SimError::InvalidParameter {
            parameter: "image buffer",
            value: path.display().to_string(),
            why: "size does not match",
        },
    )?;
    img.save(path).map_err(|e| SimError::Encode {
        what: "16-bit PNG",
        reason: format!("{}: {e}", path.display()),
    })
}

/// Writes a `w × h` 8-bit sRGB PNG of packed RGB bytes.
pub(crate) fn save_rgb8(path: &Path, w: u32, h: u32, rgb: Vec<u8>) -> Result<(), SimError> {
    image::RgbImage::from_raw(w, h, rgb)
        .ok_or(SimError::InvalidParameter {
            parameter: "rgb buffer",
            value: path.display().to_string(),
            why: "size does not match",
        })?
        .save(path)
        .map_err(|e| SimError::Encode {
            what: "RGB PNG",
            reason: format!("{}: {e}", path.display()),
        })
}

/// Writes a thermal frame as the response simulator exported it (16-bit centikelvin or 8-bit
/// grey after AGC).
pub(crate) fn save_exported(
    path: &Path,
    w: u32,
    h: u32,
    frame: ExportedFrame,
) -> Result<(), SimError> {
    match frame {
        ExportedFrame::CentiKelvin(words) => save_u16(path, w, h, words),
        ExportedFrame::Grey8(grey) => image::GrayImage::from_raw(w, h, grey)
            .ok_or(SimError::InvalidParameter {
                parameter: "grey buffer",
                value: path.display().to_string(),
                why: "size does not match",
            })?
            .save(path)
            .map_err(|e| SimError::Encode {
                what: "8-bit PNG",
                reason: format!("{}: {e}", path.display()),
            }),
    }
}

/// Depths in metres → the 16-bit millimetre words of the depth truth (0 stays 0: no surface).
pub(crate) fn depth_mm_words(depth_m: &[f64]) -> Vec<u16> {
    depth_m
        .iter()
        .map(|d| (d * 1000.0).round().clamp(0.0, 65535.0) as u16)
        .collect()
}

/// Temperatures in kelvin → centikelvin words.
pub(crate) fn centikelvin_words(temp_k: &[f64]) -> Vec<u16> {
    temp_k
        .iter()
        .map(|t| (t * 100.0).round().clamp(0.0, 65535.0) as u16)
        .collect()
}

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

/// One `images.txt` record: `cam_from_world` of image `id`, taken by camera `camera_id`.
#[derive(Debug, Clone)]
pub(crate) struct ColmapImageRecord {
    pub(crate) id: usize,
    pub(crate) cam_from_world: Rigid3,
    pub(crate) camera_id: u32,
    pub(crate) name: String,
}

/// Writes the COLMAP text model (`cameras.txt`, `images.txt`, `points3D.txt`) into
/// `sparse_dir`: PINHOLE cameras with `cx, cy` moved by +½ px to COLMAP's pixel convention,
/// images with empty 2-D feature lines, points with empty tracks.
pub(crate) fn write_colmap_text(
    sparse_dir: &Path,
    cameras: &[(u32, CameraModel)],
    images: &[ColmapImageRecord],
    points: &[(DVec3, [u8; 3])],
) -> Result<(), SimError> {
    let mut cameras_txt = format!(
        "# Camera list with one line of data per camera:\n\
         #   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n\
         # Number of cameras: {}\n",
        cameras.len()
    );
    for (id, cam) in cameras {
        let i = cam.intrinsics;
        // COLMAP puts the centre of the top-left pixel at (0.5, 0.5); ours is at (0, 0).
        cameras_txt.push_str(&format!(
            "{id} PINHOLE {} {} {:.17} {:.17} {:.17} {:.17}\n",
            cam.width_px,
            cam.height_px,
            i.fx,
            i.fy,
            i.cx + 0.5,
            i.cy + 0.5
        ));
    }
    let mut images_txt = String::from(
        "# Image list with two lines of data per image:\n\
         #   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)  (left empty: no feature tracks)\n",
    );
    images_txt.push_str(&format!(
        "# Number of images: {}, mean observations per image: 0\n",
        images.len()
    ));
    for im in images {
        // One of ±q, with w ≥ 0 (COLMAP's habit).
        let q = if im.cam_from_world.rotation.w < 0.0 {
            -im.cam_from_world.rotation
        } else {
            im.cam_from_world.rotation
        };
        let t = im.cam_from_world.translation_m;
        images_txt.push_str(&format!(
            "{} {:.17} {:.17} {:.17} {:.17} {:.17} {:.17} {:.17} {} {}\n\n",
            im.id, q.w, q.x, q.y, q.z, t.x, t.y, t.z, im.camera_id, im.name
        ));
    }
    let mut points_txt = String::from(
        "# 3D point list with one line of data per point:\n\
         #   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n",
    );
    points_txt.push_str(&format!(
        "# Number of points: {}, mean track length: 0\n",
        points.len()
    ));
    for (k, (p, c)) in points.iter().enumerate() {
        points_txt.push_str(&format!(
            "{} {:.9} {:.9} {:.9} {} {} {} 0\n",
            k + 1,
            p.x,
            p.y,
            p.z,
            c[0],
            c[1],
            c[2]
        ));
    }
    for (name, text) in [
        ("cameras.txt", cameras_txt),
        ("images.txt", images_txt),
        ("points3D.txt", points_txt),
    ] {
        let p = sparse_dir.join(name);
        let mut f = fs::File::create(&p).map_err(io(&p, "create"))?;
        f.write_all(text.as_bytes()).map_err(io(&p, "write"))?;
    }
    Ok(())
}

/// Writes `ffc.txt` (with drift, without AGC: the frames right after a flat-field correction)
/// and `response.json` (with any effect) into `out`.
pub(crate) fn write_response_files(
    out: &Path,
    effects: ResponseEffects,
    response: &ResponseSimulator,
) -> Result<(), SimError> {
    if effects.drift_step_k > 0.0 && !effects.agc {
        // What a capture session's FFC telemetry says: the frames right after a correction.
        let fresh: String = response
            .truth()
            .frames
            .iter()
            .filter(|f| f.ffc_before)
            .map(|f| f.image.clone() + "\n")
            .collect();
        let p = out.join("ffc.txt");
        fs::write(&p, fresh).map_err(io(&p, "write"))?;
    }
    if effects.any() {
        write_json(
            &out.join("response.json"),
            &response.truth(),
            "response.json",
        )?;
    }
    Ok(())
}

/// Writes `value` as pretty JSON followed by a newline.
pub(crate) fn write_json(
    path: &Path,
    value: &impl Serialize,
    what: &'static str,
) -> Result<(), SimError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| SimError::Encode {
        what,
        reason: e.to_string(),
    })?;
    fs::write(path, text + "\n").map_err(io(path, "write"))
}

/// Checks the size and view count both layouts need.
pub(crate) fn check_scene_config(cfg: &SceneConfig) -> Result<(), SimError> {
    if cfg.width_px < 2 || cfg.height_px < 2 || cfg.views == 0 {
        return Err(SimError::InvalidParameter {
            parameter: "width/height/views",
            value: format!("{}x{} x {}", cfg.width_px, cfg.height_px, cfg.views),
            why: "need at least 2x2 pixels and one view",
        });
    }
    Ok(())
}

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
/// `response.json`, see [`crate::response`]). The joint RGB + thermal layout is
/// [`crate::scene_joint::write_joint_scene_set`].
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
        images.push(ColmapImageRecord {
            id: k + 1,
            cam_from_world: *cam_from_world,
            camera_id: 1,
            name,
        });
        progress(k + 1, cfg.views);
    }
    let points = sample_surface_points(layout, 2000, &mut rng);
    write_colmap_text(&out.join("sparse/0"), &[(1, cam)], &images, &points)?;
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

/// Whether pixel `(x, y)` of a `width`-wide [`pixel_hits`] map and every pixel within
/// `margin_px` of it (a square neighbourhood) see `object`: the interior of its mask.
pub fn is_interior(
    hits: &[Option<(SceneObject, DVec3)>],
    width: usize,
    x: usize,
    y: usize,
    object: SceneObject,
    margin_px: i64,
) -> bool {
    let height = hits.len() / width.max(1);
    let object_at = |x: i64, y: i64| {
        (x >= 0 && y >= 0 && x < width as i64 && y < height as i64)
            .then(|| hits[y as usize * width + x as usize].map(|(o, _)| o))
            .flatten()
    };
    (-margin_px..=margin_px).all(|dy| {
        (-margin_px..=margin_px).all(|dx| object_at(x as i64 + dx, y as i64 + dy) == Some(object))
    })
}

/// What the centre ray of each pixel of a scene view hits (row-major, `None`: background), with
/// the world point hit: the ground truth tests build object masks from.
pub fn pixel_hits(
    layout: SceneLayout,
    cam: &CameraModel,
    cam_from_world: &Rigid3,
) -> Vec<Option<(SceneObject, DVec3)>> {
    let grid = RayGrid::new(cam);
    let world_from_cam = cam_from_world.inverse();
    let eye = world_from_cam.translation_m;
    let (w, h) = (grid.width(), grid.height());
    let mut out = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let d = world_from_cam.transform_vector(grid.centre_ray(u, v));
            out.push(trace(layout, eye, d).map(|s| (s.object, eye + d * s.t)));
        }
    }
    out
}

/// Projects a world point into a scene view (for tests and tools): pixel, OpenCV convention.
pub fn project_world(cam: &CameraModel, cam_from_world: &Rigid3, p: DVec3) -> Option<DVec2> {
    cam.project(cam_from_world.transform_point(p))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Pipe-side pixels of a view whose 5×5 neighbourhood is all pipe side (the interior).
    fn pipe_interior(hits: &[Option<(SceneObject, DVec3)>], w: usize, h: usize) -> usize {
        let side = |x: i64, y: i64| {
            x >= 0
                && y >= 0
                && (x as usize) < w
                && (y as usize) < h
                && matches!(
                    hits[y as usize * w + x as usize],
                    Some((SceneObject::PipeSide, _))
                )
        };
        (0..h as i64)
            .flat_map(|y| (0..w as i64).map(move |x| (x, y)))
            .filter(|&(x, y)| (-2..=2).all(|dy| (-2..=2).all(|dx| side(x + dx, y + dy))))
            .count()
    }

    /// Proves the geometry the trainer's end-to-end test relies on: at 64×48 with 16 views, the
    /// held-out views 0 and 8 see a pipe interior (2 px clear of its outline) of many pixels,
    /// view 8 sees the box's emissivity edge, and the pipe's interior is smooth in apparent
    /// temperature (grey body of constant ε at a temperature linear in x).
    #[test]
    fn held_out_views_see_the_pipe_interior_and_the_box_edge() {
        let cam = scene_camera(64, 48);
        let poses = orbit(16);
        let v0 = pixel_hits(SceneLayout::Objects, &cam, &poses[0]);
        let v8 = pixel_hits(SceneLayout::Objects, &cam, &poses[8]);
        let (n0, n8) = (pipe_interior(&v0, 64, 48), pipe_interior(&v8, 64, 48));
        assert!(
            n0 >= 150 && n8 >= 40,
            "pipe interior px: view 0 {n0}, view 8 {n8}"
        );
        let edge = v8
            .iter()
            .filter(|h| matches!(h, Some((SceneObject::Box, p)) if (p.x - BOX_C.x).abs() < 0.03))
            .count();
        assert!(edge >= 10, "box edge px in view 8: {edge}");
        // The pipe's surface temperature is the linear profile along x.
        for (obj, p) in v0.iter().flatten() {
            if *obj == SceneObject::PipeSide {
                let r = ((p.y - PIPE_YZ.0).powi(2) + (p.z - PIPE_YZ.1).powi(2)).sqrt();
                assert!(
                    (r - PIPE_R).abs() < 1e-9,
                    "hit point {p} off the pipe surface"
                );
                let t = pipe_temp_k(p.x);
                assert!(
                    (303.0..=333.0).contains(&t),
                    "pipe temperature {t} K at x {}",
                    p.x
                );
            }
        }
    }

    /// Proves the wall layout's geometry the trainer's Ψ_β test relies on: at 64×48 with 16
    /// views, every view (the held-out 0 and 8 included) sees only wall, even at the corner
    /// sub-samples of its corner pixels (no background, no silhouette); views 0 and 8 hold
    /// many pixels within 3 cm of the emissivity line and within σ/2 of the pipe's band on the
    /// paint > 0.3 m from the line; and the rendered radiance shows the emissivity edge (metal
    /// mirrors the warmer room, paint shows the cold wall) and the warm band on the paint.
    #[test]
    fn wall_views_see_only_wall_with_the_edge_and_the_pipe_band() {
        let cam = scene_camera(64, 48);
        let grid = RayGrid::new(&cam);
        let poses = poses(SceneLayout::Wall, 16);
        assert_eq!(poses.len(), 16, "wall poses");
        for (k, pose) in poses.iter().enumerate() {
            let hits = pixel_hits(SceneLayout::Wall, &cam, pose);
            let not_wall = hits
                .iter()
                .filter(|h| !matches!(h, Some((SceneObject::Wall, _))))
                .count();
            assert_eq!(not_wall, 0, "view {k}: {not_wall} px are not wall");
            let world_from_cam = pose.inverse();
            for (u, v, a, b) in [
                (0, 0, 0.0, 0.0),
                (63, 0, 1.0, 0.0),
                (0, 47, 0.0, 1.0),
                (63, 47, 1.0, 1.0),
            ] {
                let d = world_from_cam.transform_vector(grid.sub_ray(u, v, a, b));
                let hit = trace(SceneLayout::Wall, world_from_cam.translation_m, d);
                assert!(
                    matches!(
                        hit,
                        Some(SurfaceHit {
                            object: SceneObject::Wall,
                            ..
                        })
                    ),
                    "view {k}: corner ray of pixel ({u}, {v}) misses the wall: {hit:?}"
                );
            }
        }
        let radiometry = Radiometry::new();
        for k in [0, 8] {
            let hits = pixel_hits(SceneLayout::Wall, &cam, &poses[k]);
            let edge = hits
                .iter()
                .flatten()
                .filter(|(_, p)| (p.x - WALL_EDGE_X).abs() < 0.03)
                .count();
            let band = |(_, p): &&(SceneObject, DVec3)| {
                (p.z - WALL_PIPE_Z).abs() < 0.5 * WALL_PIPE_SIGMA && p.x < WALL_EDGE_X - 0.3
            };
            let pipe = hits.iter().flatten().filter(band).count();
            assert!(
                edge >= 60 && pipe >= 100,
                "view {k}: expected >= 60 edge px and >= 100 pipe-band px, got {edge} and {pipe}"
            );
            // Apparent temperature per pixel, from the rendered (area-averaged) radiance.
            let r = render_scene(SceneLayout::Wall, &grid, &poses[k], &radiometry);
            let mean_k = |f: &dyn Fn(&DVec3) -> bool| {
                let v: Vec<f64> = hits
                    .iter()
                    .zip(&r.radiance)
                    .filter(|(h, _)| h.is_some_and(|(_, p)| f(&p)))
                    .map(|(_, &l)| radiometry.temperature_k(l))
                    .collect();
                v.iter().sum::<f64>() / v.len().max(1) as f64
            };
            let far = |p: &DVec3| (p.z - WALL_PIPE_Z).abs() > 0.5;
            let paint = mean_k(&|p| p.x < WALL_EDGE_X - 0.1 && far(p));
            let metal = mean_k(&|p| p.x > WALL_EDGE_X + 0.1 && far(p));
            let on_band = mean_k(&|p| {
                (p.z - WALL_PIPE_Z).abs() < 0.05 && (p.x - WALL_PIPE_HOT_X).abs() < 0.1
            });
            assert!(
                (paint - 280.5).abs() < 0.5 && (metal - 289.0).abs() < 0.5,
                "view {k}: apparent paint {paint:.2} K (expected ≈ 280.5), metal {metal:.2} K \
                 (expected ≈ 289)"
            );
            assert!(
                on_band > paint + 9.0,
                "view {k}: pipe band {on_band:.2} K should be > 9 K above the paint's {paint:.2} K"
            );
        }
    }
}
