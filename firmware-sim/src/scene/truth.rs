//! The truth surface of the simulated scenes, `truth/surface.ply`: the surface the cameras of a
//! scene set see, with its apparent temperature, for scoring a mesh extracted from a trained
//! model (the trainer's `mesh --truth`). Both scene writers write it: the default layout's
//! and the joint RGB + thermal layout's (at the thermal camera's poses).
//!
//! **Points.** For every view of the set (training and held-out alike, in view order), the
//! pixel-centre rays of the thermal camera scaled by [`SURFACE_GRID_SCALE`] = 2 per axis
//! ([`surface_camera`]: `fx, fy` × 2, `c' = 2c + ½` in the OpenCV pixel convention, the same
//! 57° field of view; for a [`super::scene_camera`] this is `scene_camera(2W, 2H)`, as
//! the joint layout builds its K× camera) are traced through the scene
//! ([`super::trace`]). Every hit inside the layout's [`scoring_region`] is a
//! candidate (world metres; rays that hit nothing give none: the background is not a
//! surface; the far ground outside the camera orbit is left out: it is seen only at grazing
//! incidence, by few views).
//!
//! **Deduplication.** One point per [`SURFACE_CELL_M`] = 4 mm cube of world space
//! ([`surface_cell`]), the first candidate in view order, then row-major pixel order (top row
//! first, left to right), so the file does not depend on the thread count (rows are traced in
//! parallel, their results combined in row order). The cube lattice is offset by
//! [`SURFACE_CELL_OFFSET_M`] = 1 mm so that no axis-aligned plane of the scenes (ground z = 0,
//! wall y = 0, box faces, pipe caps, radiator) lies on a cube face, where rounding would split
//! one plane over two layers of cubes. The cube is that of the coordinates as written (f32), so
//! a reader finds exactly one point per cube.
//!
//! **Per point**: the position, the unit surface normal oriented toward the camera that saw it
//! first ([`super::SurfaceHit::normal`]), and the **apparent temperature** in kelvin:
//! what a radiometric camera, which assumes ε = 1, reads for this surface,
//! `L⁻¹(ε L(T) + (1 − ε) L(ENV_K))` ([`Radiometry::apparent_radiance`],
//! [`Radiometry::temperature_k`]). Every surface of these scenes is a grey body reflecting the
//! uniform surroundings at [`ENV_K`], so the apparent temperature does not depend on the view.
//! (Wall layout: ≈ 280.5 K on the paint, ≈ 289 K on the bare metal, up to ≈ 291.5 K on the
//! pipe's band.)
//!
//! **Format**: binary little-endian PLY, this header ([`SURFACE_PLY_COMMENT`]), then N records
//! of 7 little-endian f32 (28 bytes):
//!
//! ```text
//! ply
//! format binary_little_endian 1.0
//! comment s3tir truth surface: visible points of the simulated scene, world metres; kelvin = apparent temperature (emissivity 1)
//! comment region_m X0 Y0 Z0 X1 Y1 Z1 (evaluation volume, min and max corners xyz: a scorer scores the mesh inside it)
//! element vertex N
//! property float x
//! property float y
//! property float z
//! property float nx
//! property float ny
//! property float nz
//! property float kelvin
//! end_header
//! ```
//!
//! Written atomically: `surface.ply.tmp` beside it, then renamed. `scene.json` names it in
//! `truth_surface` ([`TruthSurfaceJson`]). Cost: 4 rays per thermal pixel and view, against the
//! 17 of a view's render (4×4 sub-samples and the centre ray); view k is traced while view
//! k − 1 is deduplicated, and only kept points get their apparent temperature. Measured at the
//! default 160×120 × 24 views on 2 cores: ≈ 70–100 ms, ≈ 30 % of the views' render time.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::Write;
use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;
use s3tir_calib::model::ply::{self, Element, Header, Ty};
use s3tir_calib::{CameraModel, Intrinsics, Rigid3};
use serde::Serialize;

use super::SceneLayout;
use super::files::io;
use super::objects::{ENV_K, trace};
use crate::error::SimError;
use crate::physics::Radiometry;
use crate::render::RayGrid;

/// The truth surface, relative to the dataset root.
pub const SURFACE_TRUTH_FILE: &str = "truth/surface.ply";
/// The tracing grid has this many times the thermal camera's pixels per axis.
pub const SURFACE_GRID_SCALE: u32 = 2;
/// Edge of the deduplication cubes, metres.
pub const SURFACE_CELL_M: f64 = 0.004;
/// Offset of the cube lattice, metres: cube `(i, j, k)` covers `[4i − 1, 4i + 3) mm` per axis.
pub const SURFACE_CELL_OFFSET_M: f64 = 0.001;
/// The PLY header's comment line (after `comment `).
pub const SURFACE_PLY_COMMENT: &str = "s3tir truth surface: visible points of the simulated \
                                       scene, world metres; kelvin = apparent temperature \
                                       (emissivity 1)";

/// One point of the truth surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// World metres (already rounded to f32, as written).
    pub position_m: [f32; 3],
    /// Unit normal (world), toward the camera that saw the point first.
    pub normal: [f32; 3],
    /// Apparent temperature (emissivity 1), kelvin.
    pub kelvin: f32,
}

/// `scene.json`'s `truth_surface` (both layouts).
#[derive(Debug, Clone, Serialize)]
pub struct TruthSurfaceJson {
    /// Relative to the dataset root: [`SURFACE_TRUTH_FILE`].
    pub path: &'static str,
    pub points: usize,
    pub format: &'static str,
    /// The camera whose pixel-centre rays were traced at every view's pose.
    pub grid_camera: CameraModel,
    pub cell_m: f64,
    pub what: &'static str,
}

impl TruthSurfaceJson {
    /// The entry of a surface of `points` points traced with `grid_camera`; `what` says at
    /// which poses.
    pub fn new(points: usize, grid_camera: CameraModel, what: &'static str) -> Self {
        Self {
            path: SURFACE_TRUTH_FILE,
            points,
            format: "binary little-endian PLY: element vertex, properties x y z nx ny nz kelvin \
                     (float32 each)",
            grid_camera,
            cell_m: SURFACE_CELL_M,
            what,
        }
    }
}

/// What the default layout's `truth_surface.what` says.
pub(crate) const SURFACE_WHAT_DEFAULT: &str = concat!(
    "the visible surface: hits of the pixel-centre rays of grid_camera (the thermal camera at ",
    "2x its resolution per axis) at every view's pose, training and held-out; one point per ",
    "4 mm cube of world space (lattice offset by 1 mm), the first in view order then ",
    "row-major; world metres; normal toward the camera that saw it; kelvin = apparent ",
    "temperature (emissivity 1) of the grey body reflecting env_k, the same from every view",
);
/// What the joint layout's `truth_surface.what` says.
pub(crate) const SURFACE_WHAT_JOINT: &str = concat!(
    "the visible surface: hits of the pixel-centre rays of grid_camera (the thermal camera at ",
    "2x its resolution per axis) at every instant's thermal pose, training and held-out; one ",
    "point per 4 mm cube of world space (lattice offset by 1 mm), the first in instant order ",
    "then row-major; world metres; normal toward the camera that saw it; kelvin = apparent ",
    "temperature (emissivity 1) of the grey body reflecting env_k, the same from every view",
);

/// The tracing camera of a thermal camera `cam`: [`SURFACE_GRID_SCALE`] times its pixels per
/// axis over the same field of view (`f × 2`, `c' = 2c + ½`, same distortion, which acts on
/// normalised coordinates).
pub fn surface_camera(cam: &CameraModel) -> Result<CameraModel, SimError> {
    let s = SURFACE_GRID_SCALE;
    let (Some(width_px), Some(height_px)) =
        (cam.width_px.checked_mul(s), cam.height_px.checked_mul(s))
    else {
        return Err(SimError::InvalidParameter {
            parameter: "truth surface grid (width/height x 2)",
            value: format!("{}x{}", cam.width_px, cam.height_px),
            why: "the tracing grid's size overflows 32 bits",
        });
    };
    let k = f64::from(s);
    // Pixel centres at integers (docs/CONVENTIONS.md): the image's left edge u = −½ maps to
    // u' = −½ and lengths scale by k, so u' = k u + (k − 1)/2.
    let shift = (k - 1.0) / 2.0;
    let i = cam.intrinsics;
    Ok(CameraModel {
        width_px,
        height_px,
        intrinsics: Intrinsics {
            fx: i.fx * k,
            fy: i.fy * k,
            cx: i.cx * k + shift,
            cy: i.cy * k + shift,
        },
        distortion: cam.distortion,
    })
}

/// The deduplication cube of a world point (metres): `floor((p + 1 mm) / 4 mm)` per axis
/// (saturating beyond ±8 000 km, far outside any scene).
pub fn surface_cell(p: [f32; 3]) -> [i32; 3] {
    p.map(|c| {
        let x = (f64::from(c) + SURFACE_CELL_OFFSET_M) / SURFACE_CELL_M;
        // floor() without the libm call (no SSE4.1 in the baseline target): truncate, then
        // step down for negative non-integers. Exact for every finite x (saturating casts).
        let t = x as i64;
        let f = if (t as f64) > x { t - 1 } else { t };
        f.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
    })
}

/// The region of `layout` the truth surface covers (min, max corners, world metres): where
/// the cameras see the scene well enough to score a reconstruction. Objects: the square
/// |x|, |y| ≤ 1 m up to 1 m high, inside the camera orbit (radius 1.6 m): beyond it the
/// ground is seen only at grazing incidence by the far cameras (≥ 2.6 m, pixel footprints
/// of several centimetres at 64 px width), where even the true depth maps fuse into no
/// surface. Wall: the part of the wall the cameras see (x ∈ ±1.5 m, z ∈ [0.1, 1.8] m) and the
/// free space in front of it (y from −1.5 m), where a reconstruction's floaters would be. The
/// PLY header states it ([`region_comment`]): a scorer scores the mesh vertices inside it.
pub fn scoring_region(layout: SceneLayout) -> ([f64; 3], [f64; 3]) {
    match layout {
        SceneLayout::Objects => ([-1.0, -1.0, -0.05], [1.0, 1.0, 1.0]),
        SceneLayout::Wall | SceneLayout::Facade => ([-1.5, -1.5, 0.1], [1.5, 0.05, 1.8]),
    }
}

/// The truth surface of `layout` seen by `cam` scaled by [`SURFACE_GRID_SCALE`] at each of
/// `poses` (`cam_from_world`), deduplicated (module docs), in output order.
pub fn surface_points(
    layout: SceneLayout,
    cam: &CameraModel,
    poses: &[Rigid3],
) -> Result<Vec<SurfacePoint>, SimError> {
    surface_points_with(layout, cam, poses, &Radiometry::new())
}

/// [`surface_points`] with the writer's `radiometry` (its table takes ~60 ms to build).
pub(crate) fn surface_points_with(
    layout: SceneLayout,
    cam: &CameraModel,
    poses: &[Rigid3],
    radiometry: &Radiometry,
) -> Result<Vec<SurfacePoint>, SimError> {
    let grid_cam = surface_camera(cam)?;
    let grid = RayGrid::new(&grid_cam);
    let (w, h) = (grid.width(), grid.height());
    let rays: Vec<DVec3> = (0..h)
        .flat_map(|v| (0..w).map(move |u| (u, v)))
        .map(|(u, v)| grid.centre_ray(u, v))
        .collect();
    let mut seen = CellSet::default();
    let mut kept = Vec::with_capacity(w * h);
    // View k is traced (in parallel) while view k − 1 is deduplicated (sequentially, in view
    // order): two buffers, swapped each view.
    let mut buffers = [ViewHits::new(w * h), ViewHits::new(w * h)];
    for k in 0..=poses.len() {
        let [even, odd] = &mut buffers;
        let (current, previous) = if k % 2 == 0 { (even, odd) } else { (odd, even) };
        rayon::join(
            || {
                if let Some(cam_from_world) = poses.get(k) {
                    current.trace(layout, &rays, w, cam_from_world);
                }
            },
            || {
                if k > 0 {
                    previous.keep_new(&mut seen, &mut kept);
                }
            },
        );
    }
    // The apparent temperature of the kept points only (a quarter to a tenth of the hits).
    Ok(kept
        .par_iter()
        .map(|c| {
            let apparent = radiometry.apparent_radiance(c.emissivity, c.temp_k, ENV_K);
            SurfacePoint {
                position_m: c.position_m,
                normal: c.normal,
                kelvin: radiometry.temperature_k(apparent) as f32,
            }
        })
        .collect())
}

/// Per ray of a view: its cube (`None`: no hit), compact so that the sequential pass over it
/// stays in cache, and the hit.
#[derive(Debug)]
struct ViewHits {
    cells: Vec<Option<[i32; 3]>>,
    hits: Vec<Candidate>,
}

impl ViewHits {
    fn new(rays: usize) -> Self {
        Self {
            cells: vec![None; rays],
            hits: vec![Candidate::default(); rays],
        }
    }

    /// Traces the `rays` (camera frame, z = 1; rows of `w`) of the view `cam_from_world`: rows
    /// in parallel, each ray computed alone into its own slots.
    fn trace(&mut self, layout: SceneLayout, rays: &[DVec3], w: usize, cam_from_world: &Rigid3) {
        if w == 0 {
            return;
        }
        let world_from_cam = cam_from_world.inverse();
        let rotation = world_from_cam.rotation_matrix();
        let eye = world_from_cam.translation_m;
        self.cells
            .par_chunks_mut(w)
            .zip(self.hits.par_chunks_mut(w))
            .zip(rays.par_chunks(w))
            .for_each(|((row_cells, row_hits), row_rays)| {
                for ((cell, hit), &ray) in row_cells.iter_mut().zip(row_hits).zip(row_rays) {
                    let d = rotation * ray;
                    let region = scoring_region(layout);
                    *cell = trace(layout, eye, d)
                        .filter(|s| {
                            let p = eye + d * s.t;
                            (0..3).all(|k| p[k] >= region.0[k] && p[k] <= region.1[k])
                        })
                        .map(|s| {
                            let p = eye + d * s.t;
                            let n = s.normal.normalize();
                            *hit = Candidate {
                                position_m: [p.x as f32, p.y as f32, p.z as f32],
                                normal: [n.x as f32, n.y as f32, n.z as f32],
                                emissivity: s.emissivity,
                                temp_k: s.temp_k,
                            };
                            surface_cell(hit.position_m)
                        });
                }
            });
    }

    /// Appends to `kept` the hits whose cube is not in `seen` yet, in row-major order.
    fn keep_new(&self, seen: &mut CellSet, kept: &mut Vec<Candidate>) {
        for (cell, hit) in self.cells.iter().zip(&self.hits) {
            if let Some(cell) = cell
                && seen.insert(*cell)
            {
                kept.push(*hit);
            }
        }
    }
}

/// A ray's hit before deduplication.
#[derive(Debug, Clone, Copy, Default)]
struct Candidate {
    position_m: [f32; 3],
    normal: [f32; 3],
    emissivity: f64,
    temp_k: f64,
}

/// The set of occupied cubes: a bitset of 16³ cubes per block, blocks found by hash (with the
/// last block remembered: consecutive candidates are mostly neighbours). It only answers
/// membership; the output order is the candidates' order. A plain `HashSet` of cubes with
/// SipHash took longer than the tracing itself.
#[derive(Debug, Default)]
struct CellSet {
    blocks: HashMap<[i32; 3], usize, BuildHasherDefault<CellHasher>>,
    bits: Vec<[u64; 64]>,
    last: Option<([i32; 3], usize)>,
}

impl CellSet {
    /// Adds `cell`; true if it was not there.
    fn insert(&mut self, cell: [i32; 3]) -> bool {
        let key = cell.map(|c| c >> 4);
        let block = match self.last {
            Some((k, b)) if k == key => b,
            _ => {
                let next = self.bits.len();
                let b = *self.blocks.entry(key).or_insert(next);
                if b == next {
                    self.bits.push([0; 64]);
                }
                self.last = Some((key, b));
                b
            }
        };
        let [x, y, z] = cell.map(|c| (c & 15) as usize);
        let bit = x | y << 4 | z << 8;
        let (word, mask) = (bit >> 6, 1u64 << (bit & 63));
        let words = &mut self.bits[block];
        let fresh = words[word] & mask == 0;
        words[word] |= mask;
        fresh
    }
}

/// A multiply-rotate hasher (FxHash's mixing) for the block keys, which are ours (no need for
/// SipHash's resistance to chosen keys).
#[derive(Debug, Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }

    fn write_i32(&mut self, x: i32) {
        self.write_u64(u64::from(x as u32));
    }

    fn write_usize(&mut self, x: usize) {
        self.write_u64(x as u64);
    }
}

/// The header comment line giving the evaluation volume of `layout` ([`scoring_region`]).
pub fn region_comment(layout: SceneLayout) -> String {
    let (lo, hi) = scoring_region(layout);
    format!(
        "region_m {} {} {} {} {} {} (evaluation volume, min and max corners xyz: a scorer \
         scores the mesh inside it)",
        lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    )
}

/// The PLY header of `n` points of `layout` (module docs).
pub fn surface_ply_header(n: usize, layout: SceneLayout) -> String {
    Header {
        comments: vec![SURFACE_PLY_COMMENT.to_owned(), region_comment(layout)],
        elements: vec![Element::scalars(
            "vertex",
            n,
            Ty::F32,
            &["x", "y", "z", "nx", "ny", "nz", "kelvin"],
        )],
    }
    .text()
}

/// Writes the truth surface of `layout` seen by the thermal camera `cam` (scaled by
/// [`SURFACE_GRID_SCALE`]) at each of `poses` (`cam_from_world`) to `path` (module docs),
/// atomically (`<path>.tmp`, then renamed); returns the number of points.
pub fn write_surface_truth(
    path: &Path,
    layout: SceneLayout,
    cam: &CameraModel,
    poses: &[Rigid3],
) -> Result<usize, SimError> {
    write_surface_truth_with(path, layout, cam, poses, &Radiometry::new())
}

/// [`write_surface_truth`] with the writer's `radiometry`.
pub(crate) fn write_surface_truth_with(
    path: &Path,
    layout: SceneLayout,
    cam: &CameraModel,
    poses: &[Rigid3],
    radiometry: &Radiometry,
) -> Result<usize, SimError> {
    let points = surface_points_with(layout, cam, poses, radiometry)?;
    let finite = |a: &[f32]| a.iter().all(|x| x.is_finite());
    if let Some(bad) = points
        .iter()
        .position(|p| !(finite(&p.position_m) && finite(&p.normal) && p.kelvin.is_finite()))
    {
        return Err(SimError::Encode {
            what: "truth surface PLY",
            reason: format!(
                "{}: point {bad} is not finite: {:?}",
                path.display(),
                points[bad]
            ),
        });
    }
    if path.file_name().is_none() {
        return Err(SimError::InvalidParameter {
            parameter: "truth surface path",
            value: path.display().to_string(),
            why: "needs a file name",
        });
    }
    ply::write_atomic(path, |w| write_points(w, &points, layout))
        .map_err(io(path, "write (atomically, through a .tmp file)"))?;
    Ok(points.len())
}

/// The header and the records of `points` (7 little-endian f32 each).
fn write_points(
    w: &mut impl Write,
    points: &[SurfacePoint],
    layout: SceneLayout,
) -> std::io::Result<()> {
    w.write_all(surface_ply_header(points.len(), layout).as_bytes())?;
    for p in points {
        let values = [
            p.position_m[0],
            p.position_m[1],
            p.position_m[2],
            p.normal[0],
            p.normal[1],
            p.normal[2],
            p.kelvin,
        ];
        for v in values {
            w.write_all(&v.to_le_bytes())?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
