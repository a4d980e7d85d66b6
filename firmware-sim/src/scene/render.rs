//! Rendering a scene view: area-averaged radiance and colour with centre-ray depth and
//! temperature ([`render_scene`]), and the per-pixel ground truth of what each pixel sees
//! ([`pixel_hits`], [`is_interior`], [`project_world`]) that tests build masks from.

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use s3tir_calib::{CameraModel, Rigid3};

use super::SceneLayout;
use super::objects::{BACKGROUND_K, BACKGROUND_RGB, ENV_K, SceneObject, trace};
use crate::physics::Radiometry;
use crate::render::RayGrid;

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
