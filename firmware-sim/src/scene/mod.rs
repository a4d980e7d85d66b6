//! Simple thermal scenes with ground truth for the trainer, written as a COLMAP text model.
//! Three layouts ([`SceneLayout`]): `Objects` (the default, below), `Wall` (further below) and
//! `Facade` (a brick facade with fine thermal texture, for a real core's resolution:
//! [`facade`]).
//! The same scenes seen by a thermal + RGB rig, RGB at K× the thermal resolution, with
//! high-resolution truth: [`joint`] (`scene --rgb-scale K`).
//!
//! Truth written beside the images: `depth/` and `temperature/` per view (camera z and true
//! surface temperature along each pixel-centre ray) and `truth/surface.ply`, the visible
//! surface of the whole set with its apparent temperature, for scoring meshes
//! ([`truth`]: the pixel-centre hits of the thermal camera at 2× its resolution
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
//!
//! ## Modules
//!
//! - [`objects`]: the surfaces of the layouts, their materials and the ray tracer;
//!   [`facade`] (`objects/facade.rs`): the `Facade` layout's brick, mortar, pipe, cabinet and
//!   labels;
//! - [`cameras`]: the scene camera and its poses (orbit, wall arc);
//! - [`render`]: rendering a view (radiance, colour, depth, temperature) and per-pixel truth;
//! - `sensing` (private): the thermal core and RGB exposure that turn a render into images;
//! - [`response`]: per-frame automatic gain control (8-bit) and drift between flat-field
//!   corrections, with their truth (`response.json`);
//! - [`truth`]: the truth surface both layouts write (`truth/surface.ply`);
//! - `meta` (private; its joint types are re-exported by [`joint`]): the `scene.json` schema;
//! - `files` (private): PNG, JSON, response and COLMAP files (through `s3tir_calib::model::colmap`);
//! - `write` (private, re-exported here): the thermal dataset writer ([`write_scene_set_with`]);
//! - [`joint`]: the joint RGB + thermal dataset writer (`scene --rgb-scale K`).

use std::path::PathBuf;

use crate::error::SimError;

pub mod cameras;
mod files;
pub mod joint;
mod meta;
pub mod objects;
pub mod render;
pub mod response;
mod sensing;
pub mod truth;
mod write;

pub use cameras::{look_at, orbit, poses, scene_camera, wall_arc};
pub use objects::facade;
pub use objects::{
    BACKGROUND_K, BOX_C, BOX_H, ENV_K, FLOOR_PIPE_PEAK_K, FLOOR_PIPE_SIGMA, FLOOR_PIPE_X, PIPE_R,
    PIPE_X, PIPE_YZ, SceneObject, SurfaceHit, WALL_BASE_K, WALL_EDGE_X, WALL_METAL_EMISSIVITY,
    WALL_PAINT_EMISSIVITY, WALL_PIPE_HOT_X, WALL_PIPE_LENGTH, WALL_PIPE_PEAK_K, WALL_PIPE_SIGMA,
    WALL_PIPE_Z, WALL_X, WALL_Y, WALL_Z, floor_temp_k, sample_surface_points, trace, wall_temp_k,
};
pub use render::{
    SCENE_SUBPIXELS, SceneRender, is_interior, pixel_hits, project_world, render_scene,
};
pub use write::{write_scene_set, write_scene_set_with, write_scene_set_with_layout};

/// Which scene [`write_scene_set_with_layout`] and friends render (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SceneLayout {
    /// Box, free-standing pipe, floor with an underfloor pipe, radiator, seen from an orbit.
    #[default]
    Objects,
    /// A wall with an emissivity edge and an in-wall heating pipe, filling every view.
    Wall,
    /// A brick facade with texture finer than the primitives (joints, labels, a pipe's
    /// edges), seen from the wall's arc ([`facade`]).
    Facade,
}

impl SceneLayout {
    /// The layout's name, as `scene --layout` takes it and `scene.json` records it.
    pub fn name(self) -> &'static str {
        match self {
            SceneLayout::Objects => "objects",
            SceneLayout::Wall => "wall",
            SceneLayout::Facade => "facade",
        }
    }
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::objects::pipe_temp_k;
    use super::*;
    use crate::physics::Radiometry;
    use crate::render::RayGrid;
    use glam::DVec3;

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
