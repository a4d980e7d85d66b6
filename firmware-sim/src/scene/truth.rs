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
use std::fs;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{BufWriter, Write};
use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;
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
        SceneLayout::Wall => ([-1.5, -1.5, 0.1], [1.5, 0.05, 1.8]),
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
    let mut s = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {SURFACE_PLY_COMMENT}\ncomment {}\n\
         element vertex {n}\n",
        region_comment(layout)
    );
    for p in ["x", "y", "z", "nx", "ny", "nz", "kelvin"] {
        s.push_str(&format!("property float {p}\n"));
    }
    s.push_str("end_header\n");
    s
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
    let Some(name) = path.file_name() else {
        return Err(SimError::InvalidParameter {
            parameter: "truth surface path",
            value: path.display().to_string(),
            why: "needs a file name",
        });
    };
    let mut tmp_name = name.to_os_string();
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    let written = write_ply(&tmp, &points, layout);
    if let Err(e) = written {
        // Best effort: the partial file is of no use to anyone.
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    fs::rename(&tmp, path).map_err(io(path, "rename the .tmp file into place"))?;
    Ok(points.len())
}

fn write_ply(tmp: &Path, points: &[SurfacePoint], layout: SceneLayout) -> Result<(), SimError> {
    let file = fs::File::create(tmp).map_err(io(tmp, "create"))?;
    let mut f = BufWriter::new(file);
    f.write_all(surface_ply_header(points.len(), layout).as_bytes())
        .map_err(io(tmp, "write"))?;
    for p in points {
        let mut rec = [0u8; 28];
        let values = [
            p.position_m[0],
            p.position_m[1],
            p.position_m[2],
            p.normal[0],
            p.normal[1],
            p.normal[2],
            p.kelvin,
        ];
        for (chunk, v) in rec.chunks_exact_mut(4).zip(values) {
            chunk.copy_from_slice(&v.to_le_bytes());
        }
        f.write_all(&rec).map_err(io(tmp, "write"))?;
    }
    f.flush().map_err(io(tmp, "flush"))
}

#[cfg(test)]
mod tests {
    //! Proves: the tracing camera is the thermal camera at 2× (as the joint layout builds its
    //! K× camera); both scene writers write `truth/surface.ply` with the documented header and
    //! N records of 7 f32, equal to [`surface_points`]; every point lies on a surface of its
    //! layout, with a unit normal facing a camera; kelvin is the apparent temperature of the
    //! surface hit (wall: ≈ 280.5 K paint, ≈ 289 K metal); one point per 4 mm cube, the first
    //! in view order; the same bytes twice and the same points on 1 and 3 threads.
    //! Does not prove the surface is complete (a point per visible cube): the grid's spacing
    //! exceeds 4 mm at small image sizes, by design.
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::scene::joint::{JointOptions, thermal_cam_from_world, write_joint_scene_set};
    use crate::scene::objects::{RAD_X, RAD_Y, RAD_Z};
    use crate::scene::response::ResponseEffects;
    use crate::scene::{
        BOX_C, BOX_H, PIPE_R, PIPE_X, PIPE_YZ, SceneConfig, WALL_EDGE_X, WALL_METAL_EMISSIVITY,
        WALL_PAINT_EMISSIVITY, WALL_PIPE_Z, WALL_X, WALL_Y, WALL_Z, floor_temp_k, poses,
        scene_camera, wall_temp_k, write_scene_set_with,
    };
    use std::collections::HashSet;
    use std::path::PathBuf;

    const W: u32 = 16;
    const H: u32 = 12;
    const VIEWS: usize = 4;
    /// Distance from a surface a written (f32) point may have, metres.
    const ON_SURFACE_M: f64 = 1e-4;

    /// A `truth/surface.ply` read back: the header's vertex count and the records.
    fn read_surface_ply(path: &Path) -> Vec<SurfacePoint> {
        let bytes =
            fs::read(path).unwrap_or_else(|e| panic!("{} should exist: {e}", path.display()));
        let end = b"end_header\n";
        let body_at = bytes
            .windows(end.len())
            .position(|w| w == end)
            .map(|i| i + end.len())
            .unwrap_or_else(|| panic!("{}: no end_header line", path.display()));
        let header = std::str::from_utf8(&bytes[..body_at]).expect("ASCII header");
        let n: usize = header
            .lines()
            .find_map(|l| l.strip_prefix("element vertex "))
            .expect("an `element vertex N` line")
            .parse()
            .expect("a vertex count");
        assert!(
            [SceneLayout::Objects, SceneLayout::Wall]
                .iter()
                .any(|&l| header == surface_ply_header(n, l)),
            "{}: expected exactly the documented header of a layout",
            path.display()
        );
        let region_line = header
            .lines()
            .find(|l| l.starts_with("comment region_m "))
            .expect("a region_m comment");
        let expected = [
            "ply",
            "format binary_little_endian 1.0",
            "comment s3tir truth surface: visible points of the simulated scene, world metres; \
             kelvin = apparent temperature (emissivity 1)",
            region_line,
            &format!("element vertex {n}"),
            "property float x",
            "property float y",
            "property float z",
            "property float nx",
            "property float ny",
            "property float nz",
            "property float kelvin",
            "end_header",
        ];
        assert_eq!(
            header.lines().collect::<Vec<_>>(),
            expected,
            "the header, line by line"
        );
        let body = &bytes[body_at..];
        assert_eq!(
            body.len(),
            28 * n,
            "{}: expected {n} records of 7 f32 (28 bytes) after the header",
            path.display()
        );
        body.chunks_exact(28)
            .map(|r| {
                let f = |i: usize| f32::from_le_bytes(r[4 * i..4 * i + 4].try_into().unwrap());
                SurfacePoint {
                    position_m: [f(0), f(1), f(2)],
                    normal: [f(3), f(4), f(5)],
                    kelvin: f(6),
                }
            })
            .collect()
    }

    fn cfg(dir: PathBuf) -> SceneConfig {
        SceneConfig {
            out_dir: dir,
            views: VIEWS,
            width_px: W,
            height_px: H,
            seed: 7,
        }
    }

    fn v(p: [f32; 3]) -> DVec3 {
        DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
    }

    /// The apparent temperature (emissivity 1) of a grey body at `temp_k`, ε `emissivity`.
    fn apparent_k(emissivity: f64, temp_k: f64) -> f64 {
        static RADIOMETRY: std::sync::OnceLock<Radiometry> = std::sync::OnceLock::new();
        let r = RADIOMETRY.get_or_init(Radiometry::new);
        r.temperature_k(r.apparent_radiance(emissivity, temp_k, ENV_K))
    }

    /// Which Objects surface `p` lies on (within [`ON_SURFACE_M`]), if any.
    fn objects_surface(p: DVec3) -> Option<&'static str> {
        let tol = ON_SURFACE_M;
        let radial = ((p.y - PIPE_YZ.0).powi(2) + (p.z - PIPE_YZ.1).powi(2)).sqrt();
        let lo = BOX_C - DVec3::splat(BOX_H);
        let hi = BOX_C + DVec3::splat(BOX_H);
        let in_box = (0..3).all(|k| p[k] >= lo[k] - tol && p[k] <= hi[k] + tol);
        let on_box_face = (0..3).any(|k| (p[k] - lo[k]).abs() < tol || (p[k] - hi[k]).abs() < tol);
        if p.z.abs() < tol && p.x.abs() <= 2.0 + tol && p.y.abs() <= 2.0 + tol {
            Some("ground")
        } else if (radial - PIPE_R).abs() < tol && p.x >= PIPE_X.0 - tol && p.x <= PIPE_X.1 + tol {
            Some("pipe side")
        } else if ((p.x - PIPE_X.0).abs() < tol || (p.x - PIPE_X.1).abs() < tol)
            && radial <= PIPE_R + tol
        {
            Some("pipe cap")
        } else if in_box && on_box_face {
            Some("box")
        } else if (p.x - RAD_X).abs() < tol
            && p.y >= RAD_Y.0 - tol
            && p.y <= RAD_Y.1 + tol
            && p.z >= RAD_Z.0 - tol
            && p.z <= RAD_Z.1 + tol
        {
            Some("radiator")
        } else {
            None
        }
    }

    /// Checks shared by both layouts: count, normals facing a camera, kelvin range, one point
    /// per cube, and the file equals [`surface_points`].
    fn check_common(
        what: &str,
        points: &[SurfacePoint],
        layout: SceneLayout,
        cam: &CameraModel,
        poses: &[Rigid3],
    ) {
        assert!(
            !points.is_empty(),
            "{what}: expected surface points, got none"
        );
        let expected = surface_points(layout, cam, poses).unwrap();
        assert!(
            points == expected.as_slice(),
            "{what}: the file should hold exactly surface_points() ({} points), has {}",
            expected.len(),
            points.len()
        );
        let eyes: Vec<DVec3> = poses.iter().map(|p| p.inverse().translation_m).collect();
        let mut cells = HashSet::new();
        for (i, q) in points.iter().enumerate() {
            let (p, n) = (v(q.position_m), v(q.normal));
            assert!(
                (n.length() - 1.0).abs() < 1e-5,
                "{what}: point {i} normal {n} should be a unit vector"
            );
            assert!(
                eyes.iter().any(|&e| (e - p).dot(n) > 0.0),
                "{what}: point {i} at {p}: normal {n} should face one of the cameras"
            );
            assert!(
                (270.0..=340.0).contains(&q.kelvin),
                "{what}: point {i} at {p}: expected 270..340 K, got {} K",
                q.kelvin
            );
            assert!(
                cells.insert(surface_cell(q.position_m)),
                "{what}: point {i} at {p} shares its 4 mm cube {:?} with an earlier point",
                surface_cell(q.position_m)
            );
        }
    }

    #[test]
    fn surface_camera_is_the_thermal_camera_at_twice_the_resolution() {
        let cam = scene_camera(W, H);
        let s = surface_camera(&cam).unwrap();
        let joint = JointOptions {
            rgb_scale: 2,
            low_light: false,
        }
        .rgb_camera(W, H)
        .unwrap();
        for (other, name) in [
            (scene_camera(2 * W, 2 * H), "scene_camera(2W, 2H)"),
            (joint, "the joint layout's 2x RGB camera"),
        ] {
            assert_eq!(
                (s.width_px, s.height_px),
                (other.width_px, other.height_px),
                "size vs {name}"
            );
            let (a, b) = (s.intrinsics, other.intrinsics);
            for (x, y, p) in [
                (a.fx, b.fx, "fx"),
                (a.fy, b.fy, "fy"),
                (a.cx, b.cx, "cx"),
                (a.cy, b.cy, "cy"),
            ] {
                assert!((x - y).abs() < 1e-12, "{p}: {x} should equal {name}'s {y}");
            }
        }
        assert_eq!(
            (s.intrinsics.cx, s.intrinsics.cy),
            (2.0 * cam.intrinsics.cx + 0.5, 2.0 * cam.intrinsics.cy + 0.5),
            "c' = 2c + 1/2"
        );
    }

    #[test]
    fn wall_scene_writes_the_wall_with_its_apparent_temperatures() {
        let tmp = tempfile::tempdir().unwrap();
        let c = cfg(tmp.path().join("wall"));
        write_scene_set_with(
            &c,
            SceneLayout::Wall,
            ResponseEffects::default(),
            &mut |_, _| {},
        )
        .unwrap();
        let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
        let cam = scene_camera(W, H);
        let poses = poses(SceneLayout::Wall, VIEWS);
        check_common("wall", &points, SceneLayout::Wall, &cam, &poses);
        let (mut paint, mut metal) = (Vec::new(), Vec::new());
        for (i, q) in points.iter().enumerate() {
            let p = v(q.position_m);
            assert!(
                (p.y - WALL_Y).abs() < ON_SURFACE_M
                    && p.x >= WALL_X.0 - ON_SURFACE_M
                    && p.x <= WALL_X.1 + ON_SURFACE_M
                    && p.z >= WALL_Z.0 - ON_SURFACE_M
                    && p.z <= WALL_Z.1 + ON_SURFACE_M,
                "wall: point {i} at {p} should lie on the wall y = {WALL_Y}"
            );
            assert!(
                v(q.normal).distance(DVec3::NEG_Y) < 1e-6,
                "wall: point {i}: normal {:?} should be -y (toward the cameras)",
                q.normal
            );
            let eps = if p.x < WALL_EDGE_X {
                WALL_PAINT_EMISSIVITY
            } else {
                WALL_METAL_EMISSIVITY
            };
            let want = apparent_k(eps, wall_temp_k(p.x, p.z));
            assert!(
                (f64::from(q.kelvin) - want).abs() < 2e-3,
                "wall: point {i} at {p}: expected apparent {want:.3} K, got {} K",
                q.kelvin
            );
            if (p.z - WALL_PIPE_Z).abs() > 0.5 && (p.x - WALL_EDGE_X).abs() > 0.05 {
                if p.x < WALL_EDGE_X {
                    &mut paint
                } else {
                    &mut metal
                }
                .push(f64::from(q.kelvin));
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        assert!(
            paint.len() > 20 && metal.len() > 20,
            "wall: expected > 20 points each on paint and metal away from the pipe, got {} and {}",
            paint.len(),
            metal.len()
        );
        let (pk, mk) = (mean(&paint), mean(&metal));
        assert!(
            (pk - 280.5).abs() < 0.3 && (mk - 289.0).abs() < 0.3,
            "wall: expected ≈ 280.5 K on the paint and ≈ 289 K on the metal, got {pk:.3} and \
             {mk:.3} K"
        );
        let meta: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(c.out_dir.join("scene.json")).unwrap())
                .unwrap();
        assert_eq!(
            meta["truth_surface"]["path"], SURFACE_TRUTH_FILE,
            "scene.json truth_surface.path"
        );
        assert_eq!(
            meta["truth_surface"]["points"],
            points.len(),
            "scene.json truth_surface.points should be the file's count"
        );
    }

    #[test]
    fn objects_scene_writes_points_on_its_surfaces() {
        let tmp = tempfile::tempdir().unwrap();
        let c = cfg(tmp.path().join("objects"));
        write_scene_set_with(
            &c,
            SceneLayout::Objects,
            ResponseEffects::default(),
            &mut |_, _| {},
        )
        .unwrap();
        let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
        let cam = scene_camera(W, H);
        let poses = poses(SceneLayout::Objects, VIEWS);
        check_common("objects", &points, SceneLayout::Objects, &cam, &poses);
        let mut counts: std::collections::BTreeMap<&str, usize> = Default::default();
        for (i, q) in points.iter().enumerate() {
            let p = v(q.position_m);
            let surface = objects_surface(p)
                .unwrap_or_else(|| panic!("objects: point {i} at {p} lies on no scene surface"));
            *counts.entry(surface).or_default() += 1;
            let want = match surface {
                "ground" => Some(apparent_k(0.95, floor_temp_k(p.x))),
                "box" => Some(apparent_k(if p.x < BOX_C.x { 0.95 } else { 0.12 }, 313.0)),
                _ => None,
            };
            if let Some(want) = want {
                assert!(
                    (f64::from(q.kelvin) - want).abs() < 2e-3,
                    "objects: {surface} point {i} at {p}: expected apparent {want:.3} K, got {} K",
                    q.kelvin
                );
            }
        }
        for s in ["ground", "pipe side", "box", "radiator"] {
            assert!(
                counts.get(s).copied().unwrap_or(0) > 0,
                "objects: expected points on the {s}; per surface: {counts:?}"
            );
        }
    }

    #[test]
    fn joint_scene_writes_the_surface_at_the_thermal_poses() {
        let tmp = tempfile::tempdir().unwrap();
        let c = cfg(tmp.path().join("joint"));
        let joint = JointOptions {
            rgb_scale: 2,
            low_light: false,
        };
        write_joint_scene_set(
            &c,
            SceneLayout::Wall,
            ResponseEffects::default(),
            &joint,
            &mut |_, _| {},
        )
        .unwrap();
        let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
        let thermal: Vec<Rigid3> = poses(SceneLayout::Wall, VIEWS)
            .iter()
            .map(thermal_cam_from_world)
            .collect();
        check_common(
            "joint",
            &points,
            SceneLayout::Wall,
            &scene_camera(W, H),
            &thermal,
        );
        let meta: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(c.out_dir.join("scene.json")).unwrap())
                .unwrap();
        assert_eq!(
            meta["truth_surface"]["points"],
            points.len(),
            "joint scene.json truth_surface.points should be the file's count"
        );
        assert!(
            !c.out_dir.join("truth/surface.ply.tmp").exists(),
            "the temporary file should be renamed away"
        );
    }

    #[test]
    fn deduplication_keeps_the_first_hit_in_view_order() {
        let cam = scene_camera(W, H);
        let p = poses(SceneLayout::Objects, VIEWS);
        let one = surface_points(SceneLayout::Objects, &cam, &p[..1]).unwrap();
        let twice = surface_points(SceneLayout::Objects, &cam, &[p[0], p[0]]).unwrap();
        assert!(
            one == twice,
            "a view seen twice should add no point: {} vs {}",
            one.len(),
            twice.len()
        );
        let two = surface_points(SceneLayout::Objects, &cam, &p[..2]).unwrap();
        assert!(
            two.len() > one.len() && two[..one.len()] == one[..],
            "view 1's points should follow view 0's unchanged ({} then {})",
            one.len(),
            two.len()
        );
        // Finer than 4 mm on the wall (320×240 → 640×480 rays, ≈ 2.7 mm apart at 1.6 m): cubes
        // merge rays within a view, and still hold one point each.
        let fine = surface_points(
            SceneLayout::Wall,
            &scene_camera(320, 240),
            &poses(SceneLayout::Wall, 1),
        )
        .unwrap();
        let cells: HashSet<_> = fine.iter().map(|q| surface_cell(q.position_m)).collect();
        assert!(
            fine.len() < 640 * 480 && cells.len() == fine.len(),
            "fine grid: expected fewer points than the 307200 rays, one per cube; got {} points \
             in {} cubes",
            fine.len(),
            cells.len()
        );
    }

    #[test]
    fn output_is_the_same_twice_and_on_any_thread_count() {
        let tmp = tempfile::tempdir().unwrap();
        let cam = scene_camera(W, H);
        let p = poses(SceneLayout::Objects, VIEWS);
        let (a, b) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"));
        let na = write_surface_truth(&a, SceneLayout::Objects, &cam, &p).unwrap();
        let nb = write_surface_truth(&b, SceneLayout::Objects, &cam, &p).unwrap();
        assert_eq!(na, nb, "point counts of two runs");
        assert!(
            fs::read(&a).unwrap() == fs::read(&b).unwrap(),
            "two runs should write identical bytes"
        );
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| surface_points(SceneLayout::Objects, &cam, &p).unwrap())
        };
        assert!(
            on(1) == on(3),
            "1 and 3 threads should give the same points"
        );
    }
}
