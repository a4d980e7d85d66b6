//! `s3tir-train mesh`: a trained run's views rendered, fused and extracted (module docs of
//! [`crate::mesh`] for the fusion and the extraction).
//!
//! 1. **Render** every training view of the run (both image sets of a joint run: each camera at
//!    its own resolution) on the chosen backend: the **expected depth** `depth / alpha` where
//!    `alpha ≥ min_alpha` (the depth G-buffer both backends back-propagate, the one the
//!    gradient alignment loss shapes; a median depth would need a second pass over the sorted
//!    primitives that neither backend has), the surface temperature `thermal / alpha` in kelvin
//!    (the thermal G-buffer holds `Σ w T` with no background), and the surface colour
//!    `rgb / alpha` when the model has colour. The renders are kept (depth and kelvin as f32,
//!    colour as 8-bit): 100 views at 640×512 hold ~360 MB with colour, ~260 MB without.
//! 2. **Size** the volume: the voxel edge is `--voxel-size-m`, or the scene's extent (the 1st
//!    to 99th percentile box of the rendered surface points, so a stray floater does not set
//!    it) over `--resolution`, but not finer than the median pixel footprint (depth / focal
//!    length) of the views: finer, the volume resolves only the renders' depth noise; then the blocks the surfaces touch are counted, and while they would
//!    exceed `--memory-budget` the voxel grows (block count falls with the voxel's square on
//!    surfaces). An explicit `--voxel-size-m` that does not fit is an error, not a silent change.
//! 3. **Fuse** each view into the sparse TSDF (truncation `--trunc` voxels), then **extract**.
//! 4. **Write** `OUT` (kelvin per vertex, the run's colour when it has one) and
//!    `OUT_thermal.ply` (the same mesh coloured by the ironbow palette over the 1st–99th
//!    percentile of the vertex temperatures, for viewers that show only RGB). Both are written
//!    beside and renamed, after everything else succeeded: an error leaves existing files as
//!    they were.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::error::MeshError;
use super::extract::{Mesh, extract};
use super::plyio::{read_mesh_ply, read_region, thermal_colours, write_mesh_ply};
use super::score::{MeshScore, score};
use super::tsdf::{Frame, Volume};
use crate::camera::PinholeCamera;
use crate::dataset::{Dataset, ThermalRange};
use crate::primitive::Primitives;
use crate::train::{Backend, TrainError, files};

/// The truth surface a simulated scene writes (`s3tir-firmware-sim scene`), relative to the
/// dataset.
pub const TRUTH_SURFACE: &str = "truth/surface.ply";

/// Options of [`mesh_run`] (the CLI's flags).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshOptions {
    /// Voxel edge, metres (`None`: from the extent, the resolution and the budget).
    pub voxel_m: Option<f64>,
    /// Voxels along the scene's longest side when the voxel is automatic.
    pub resolution: usize,
    /// Truncation distance, voxels.
    pub trunc_voxels: f64,
    /// Memory budget of the volume, bytes.
    pub memory_budget_bytes: u64,
    /// Alpha from which a rendered pixel is surface.
    pub min_alpha: f32,
    /// Observation weight a voxel needs to take part in the surface, in head-on-equivalent
    /// views (each view weighs `|cos θ|` of its incidence: [`super::tsdf`]).
    pub min_weight: f32,
    /// F-score threshold of the truth score, metres.
    pub tau_m: f64,
}

impl Default for MeshOptions {
    fn default() -> Self {
        Self {
            voxel_m: None,
            resolution: 512,
            trunc_voxels: 3.0,
            memory_budget_bytes: 1 << 30,
            min_alpha: 0.5,
            min_weight: 1.0,
            tau_m: 0.02,
        }
    }
}

/// Where the work is (the CLI draws it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshStage {
    Render,
    Fuse,
    Extract,
}

/// What [`mesh_views`] did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshStats {
    /// Views fused (those with any opaque pixel).
    pub views: usize,
    /// Views rendered.
    pub views_rendered: usize,
    pub voxel_m: f64,
    pub trunc_m: f64,
    pub blocks: usize,
    /// Memory of the volume, bytes.
    pub volume_bytes: usize,
    /// Memory of the kept renders, bytes.
    pub renders_bytes: usize,
    pub vertices: usize,
    pub triangles: usize,
    pub render_s: f64,
    pub fuse_s: f64,
    pub extract_s: f64,
}

/// What [`mesh_run`] wrote.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshSummary {
    pub run_dir: PathBuf,
    pub out: PathBuf,
    /// The colour-mapped copy.
    pub thermal_out: PathBuf,
    pub backend: String,
    #[serde(flatten)]
    pub stats: MeshStats,
    /// Vertex temperature range of the colour map, kelvin (the normalised unit when not
    /// `radiometric`).
    pub kelvin_lo: f32,
    pub kelvin_hi: f32,
    /// Whether the vertices carry the run's colour.
    pub colour: bool,
    /// Whether the `kelvin` values are kelvin (else the run's normalised thermal value).
    pub radiometric: bool,
    pub seconds: f64,
    /// Peak resident memory of the process (Linux `VmHWM`), bytes.
    pub peak_rss_bytes: Option<u64>,
    /// Against the dataset's truth surface (`--truth`).
    pub truth: Option<MeshScore>,
}

/// One rendered view, as kept for fusion.
struct Rendered {
    camera: PinholeCamera,
    depth_m: Vec<f32>,
    kelvin: Vec<f32>,
    /// Interleaved 8-bit colour (empty: no colour).
    rgb8: Vec<[u8; 3]>,
    opaque: usize,
}

impl Rendered {
    fn bytes(&self) -> usize {
        self.depth_m.len() * 4 + self.kelvin.len() * 4 + self.rgb8.len() * 3
    }
}

fn render_view<B: Backend>(
    backend: &mut B,
    prims: &Primitives<f32>,
    camera: &PinholeCamera,
    range: &ThermalRange,
    min_alpha: f32,
    colour: bool,
) -> Result<Rendered, MeshError> {
    let gb = backend
        .render(prims, camera)
        .map_err(|e| MeshError::Train(TrainError::Render(e)))?;
    let n = gb.width * gb.height;
    let mut depth_m = vec![f32::NAN; n];
    let mut kelvin = vec![f32::NAN; n];
    let mut rgb8 = if colour && gb.rgb.len() == 3 * n {
        vec![[0u8; 3]; n]
    } else {
        Vec::new()
    };
    let mut opaque = 0;
    for p in 0..n {
        let a = gb.alpha[p];
        if !(a >= min_alpha && a > 0.0) {
            continue;
        }
        let d = gb.depth[p] / a;
        if !d.is_finite() || d <= 0.0 {
            continue;
        }
        depth_m[p] = d;
        let t = f64::from(gb.thermal[p] / a);
        kelvin[p] = range.kelvin(t).unwrap_or(t) as f32;
        if !rgb8.is_empty() {
            rgb8[p] =
                [0, 1, 2].map(|c| ((gb.rgb[c * n + p] / a).clamp(0.0, 1.0) * 255.0).round() as u8);
        }
        opaque += 1;
    }
    Ok(Rendered {
        camera: *camera,
        depth_m,
        kelvin,
        rgb8,
        opaque,
    })
}

/// World points of every `stride`-th opaque pixel of a view, and their pixel footprints
/// (depth / focal length, metres).
fn surface_points(r: &Rendered, stride: usize, out: &mut Vec<[f64; 3]>, footprints: &mut Vec<f64>) {
    let cam = &r.camera;
    let world_from_cam = cam.cam_from_world.inverse();
    for (p, &d) in r.depth_m.iter().enumerate().step_by(stride.max(1)) {
        if !d.is_finite() {
            continue;
        }
        let (u, v) = ((p % cam.width) as f64, (p / cam.width) as f64);
        let d = f64::from(d);
        let c = glam::DVec3::new(
            (u - cam.cx_px) / cam.fx_px * d,
            (v - cam.cy_px) / cam.fy_px * d,
            d,
        );
        let w = world_from_cam.transform_point(c);
        out.push([w.x, w.y, w.z]);
        footprints.push(d / cam.fx_px.max(cam.fy_px));
    }
}

/// The longest side of the 1st–99th percentile box of `points`.
fn robust_extent_m(points: &mut [[f64; 3]]) -> f64 {
    let n = points.len();
    if n == 0 {
        return 0.0;
    }
    let (lo_i, hi_i) = (n / 100, (n - 1) - n / 100);
    let mut side: f64 = 0.0;
    for axis in 0..3 {
        points.sort_by(|a, b| a[axis].total_cmp(&b[axis]));
        side = side.max(points[hi_i][axis] - points[lo_i][axis]);
    }
    side
}

fn frame_of<'a>(r: &'a Rendered, rgb_planes: &'a [f32]) -> Frame<'a> {
    Frame {
        camera: &r.camera,
        depth_m: &r.depth_m,
        kelvin: &r.kelvin,
        rgb: (!rgb_planes.is_empty()).then_some(rgb_planes),
    }
}

fn planes_of(r: &Rendered, out: &mut Vec<f32>) {
    out.clear();
    if r.rgb8.is_empty() {
        return;
    }
    let n = r.rgb8.len();
    out.resize(3 * n, 0.0);
    for (p, c) in r.rgb8.iter().enumerate() {
        for k in 0..3 {
            out[k * n + p] = f32::from(c[k]) / 255.0;
        }
    }
}

/// Blocks the surfaces of `views` touch at voxel `voxel_m`; counting stops after the view that
/// passes `limit` blocks (the volume is over budget: the exact figure does not matter).
fn count_blocks(
    views: &[Rendered],
    voxel_m: f64,
    trunc_m: f64,
    limit: usize,
) -> std::collections::HashSet<[i32; 3]> {
    let mut keys = std::collections::HashSet::new();
    let empty: [f32; 0] = [];
    for r in views {
        Volume::touched_blocks(&frame_of(r, &empty), voxel_m, trunc_m, &mut keys);
        if keys.len() > limit {
            break;
        }
    }
    keys
}

/// Fewest views with an opaque surface a mesh is fused from.
const MIN_VIEWS: usize = 2;

/// Renders every camera (progress per view); views with no opaque pixel are left out, and
/// fewer than [`MIN_VIEWS`] left is an error.
fn render_all<B: Backend>(
    prims: &Primitives<f32>,
    cameras: &[PinholeCamera],
    range: &ThermalRange,
    opts: &MeshOptions,
    backend: &mut B,
    progress: &mut dyn FnMut(MeshStage, usize, usize),
) -> Result<Vec<Rendered>, MeshError> {
    let colour = !prims.sh.is_empty();
    let mut views = Vec::with_capacity(cameras.len());
    for (i, cam) in cameras.iter().enumerate() {
        let r = render_view(backend, prims, cam, range, opts.min_alpha, colour)?;
        if r.opaque > 0 {
            views.push(r);
        }
        progress(MeshStage::Render, i + 1, cameras.len());
    }
    if views.is_empty() {
        return Err(MeshError::NoOpaqueSurface {
            views: cameras.len(),
            min_alpha: opts.min_alpha,
        });
    }
    if views.len() < MIN_VIEWS {
        return Err(MeshError::TooFewViews {
            views: views.len(),
            required: MIN_VIEWS,
        });
    }
    Ok(views)
}

/// The voxel to start from: `--voxel-size-m` (fixed), else the surfaces' robust extent over
/// `--resolution`, never finer than a pixel's footprint. Returns (voxel, fixed).
fn initial_voxel(views: &[Rendered], opts: &MeshOptions) -> Result<(f64, bool), MeshError> {
    match opts.voxel_m {
        Some(v) if v.is_finite() && v > 0.0 => Ok((v, true)),
        Some(v) => Err(MeshError::Run {
            reason: format!("--voxel-size-m {v}: expected a positive length in metres"),
        }),
        None => {
            let (mut pts, mut footprints) = (Vec::new(), Vec::new());
            for r in views {
                surface_points(r, 7, &mut pts, &mut footprints);
            }
            let extent = robust_extent_m(&mut pts);
            footprints.sort_by(f64::total_cmp);
            let footprint = footprints.get(footprints.len() / 2).copied().unwrap_or(0.0);
            if extent.is_nan() || extent <= 0.0 {
                return Err(MeshError::EmptyVolume {
                    reason: format!(
                        "the rendered surfaces of {} views span no volume (extent {extent} m)",
                        views.len()
                    ),
                });
            }
            // Finer than a pixel's footprint the volume resolves only the renders' depth
            // noise, and neighbouring pixels' depths differ by more than the truncation
            // (pinholes where the extraction takes them for occlusion boundaries).
            Ok((
                (extent / opts.resolution.max(1) as f64).max(footprint),
                false,
            ))
        }
    }
}

/// The sparse volume, its blocks allocated: the voxel grows (unless fixed) until the blocks
/// near the surfaces fit `--memory-budget-mib`.
fn size_volume(views: &[Rendered], opts: &MeshOptions, colour: bool) -> Result<Volume, MeshError> {
    let budget = opts.memory_budget_bytes;
    let per_block = Volume::bytes_per_block(colour) as u64;
    // Counting stops at 4× the budget's blocks: enough to estimate how much the voxel grows.
    let limit = usize::try_from(budget / per_block.max(1))
        .unwrap_or(usize::MAX)
        .saturating_mul(4);
    let (mut voxel_m, fixed) = initial_voxel(views, opts)?;
    let mut keys = count_blocks(views, voxel_m, opts.trunc_voxels * voxel_m, limit);
    for _ in 0..32 {
        let need = keys.len() as u64 * per_block;
        if need <= budget {
            break;
        }
        if fixed {
            return Err(MeshError::OverBudget {
                blocks: keys.len(),
                budget_bytes: budget,
                voxel_m,
            });
        }
        // Surface blocks scale with the voxel's inverse square; a little more keeps the loop
        // short.
        voxel_m *= ((need as f64 / budget as f64).sqrt() * 1.05).max(1.05);
        keys = count_blocks(views, voxel_m, opts.trunc_voxels * voxel_m, limit);
    }
    if keys.len() as u64 * per_block > budget {
        return Err(MeshError::OverBudget {
            blocks: keys.len(),
            budget_bytes: budget,
            voxel_m,
        });
    }
    if keys.is_empty() {
        return Err(MeshError::EmptyVolume {
            reason: "no block of the volume is within the truncation distance of a surface".into(),
        });
    }
    let trunc_m = opts.trunc_voxels * voxel_m;
    let mut volume = Volume::new(voxel_m, trunc_m, colour);
    let mut sorted: Vec<[i32; 3]> = keys.into_iter().collect();
    sorted.sort_unstable();
    volume.allocate(sorted);
    Ok(volume)
}

/// Renders `cameras` of `prims` on `backend`, fuses and extracts the mesh. `range` converts the
/// normalised thermal head to kelvin (a non-radiometric range leaves the normalised value).
pub fn mesh_views<B: Backend>(
    prims: &Primitives<f32>,
    cameras: &[PinholeCamera],
    range: &ThermalRange,
    opts: &MeshOptions,
    backend: &mut B,
    progress: &mut dyn FnMut(MeshStage, usize, usize),
) -> Result<(Mesh, MeshStats), MeshError> {
    if cameras.len() < MIN_VIEWS {
        return Err(MeshError::TooFewViews {
            views: cameras.len(),
            required: MIN_VIEWS,
        });
    }
    let colour = !prims.sh.is_empty();
    let t0 = Instant::now();
    let views = render_all(prims, cameras, range, opts, backend, progress)?;
    let render_s = t0.elapsed().as_secs_f64();
    let renders_bytes = views.iter().map(Rendered::bytes).sum();
    let t1 = Instant::now();
    let mut volume = size_volume(&views, opts, colour)?;
    let (voxel_m, trunc_m) = (volume.voxel_m(), volume.trunc_m());

    // Fuse.
    let mut planes = Vec::new();
    for (i, r) in views.iter().enumerate() {
        planes_of(r, &mut planes);
        volume.integrate(&frame_of(r, &planes));
        progress(MeshStage::Fuse, i + 1, views.len());
    }
    let fuse_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    progress(MeshStage::Extract, 0, 1);
    let mesh = extract(&volume, opts.min_weight);
    progress(MeshStage::Extract, 1, 1);
    let extract_s = t2.elapsed().as_secs_f64();
    if mesh.triangles.is_empty() {
        return Err(MeshError::EmptyVolume {
            reason: format!(
                "the fused volume ({} blocks of {voxel_m:.4} m voxels, {} views) holds no \
                 surface crossing observed with weight ≥ {} (head-on-equivalent views)",
                volume.blocks(),
                views.len(),
                opts.min_weight
            ),
        });
    }
    let stats = MeshStats {
        views: views.len(),
        views_rendered: cameras.len(),
        voxel_m,
        trunc_m,
        blocks: volume.blocks(),
        volume_bytes: volume.memory_bytes(),
        renders_bytes,
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        render_s,
        fuse_s,
        extract_s,
    };
    Ok((mesh, stats))
}

/// Peak resident memory of this process (Linux `VmHWM`), bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// `OUT_thermal.ply` beside `OUT`.
pub fn thermal_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or_else(|| "mesh".to_owned(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}_thermal.ply"))
}

/// Meshes the run in `run_dir` (its PLY, or its checkpoint when there is no PLY yet) from its
/// training views into `out` and `OUT_thermal.ply`; with `truth`, scores the mesh against the
/// dataset's [`TRUTH_SURFACE`].
pub fn mesh_run<B: Backend>(
    run_dir: &Path,
    out: &Path,
    opts: &MeshOptions,
    truth: bool,
    mut backend: B,
    progress: &mut dyn FnMut(MeshStage, usize, usize),
) -> Result<MeshSummary, MeshError> {
    let start = Instant::now();
    let cfg = crate::train::load_config(run_dir)?;
    let truth_path = cfg.data.join(TRUTH_SURFACE);
    if truth && !truth_path.is_file() {
        return Err(MeshError::Run {
            reason: format!(
                "no truth surface at {} (written by `s3tir-firmware-sim scene`)",
                truth_path.display()
            ),
        });
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty())
        && !dir.is_dir()
    {
        return Err(MeshError::Run {
            reason: format!("the output folder {} does not exist", dir.display()),
        });
    }
    let data = Dataset::load(&cfg.data, &cfg.load).map_err(TrainError::from)?;
    let range = data.range.ok_or_else(|| MeshError::Run {
        reason: format!(
            "the dataset {} has no thermal images: the mesh carries temperature",
            cfg.data.display()
        ),
    })?;
    let ply = run_dir.join(files::PLY);
    let prims: Primitives<f32> = if ply.exists() {
        crate::ply::read_ply(&ply).map_err(TrainError::from)?
    } else {
        crate::checkpoint::load(&run_dir.join(files::CHECKPOINT))
            .map_err(TrainError::from)?
            .primitives
    };
    let cameras: Vec<PinholeCamera> = data.train.iter().map(|&i| data.views[i].camera).collect();
    let backend_name = backend.name().to_owned();
    let (mesh, stats) = mesh_views(&prims, &cameras, &range, opts, &mut backend, progress)?;
    let truth_score = if truth {
        let t = read_mesh_ply(&truth_path)?;
        let region = read_region(&truth_path)?;
        Some(score(&mesh, &t, opts.tau_m, region.as_ref()))
    } else {
        None
    };
    let units = if range.radiometric() {
        "kelvin: the run's rendered apparent temperature (emissivity 1), fused over the views"
    } else {
        "kelvin: NOT radiometric data; the run's normalised thermal value in [0, 1], fused"
    };
    let (colours, lo, hi) = thermal_colours(&mesh.kelvin);
    let thermal_out = thermal_path(out);
    write_mesh_ply(out, &mesh, None, units)?;
    write_mesh_ply(
        &thermal_out,
        &mesh,
        Some(&colours),
        &format!(
            "{units}; colours: ironbow from {lo:.2} to {hi:.2} {}",
            if range.radiometric() {
                "K"
            } else {
                "(normalised)"
            }
        ),
    )?;
    Ok(MeshSummary {
        run_dir: run_dir.to_path_buf(),
        out: out.to_path_buf(),
        thermal_out,
        backend: backend_name,
        colour: mesh.rgb.is_some(),
        radiometric: range.radiometric(),
        stats,
        kelvin_lo: lo,
        kelvin_hi: hi,
        seconds: start.elapsed().as_secs_f64(),
        peak_rss_bytes: peak_rss_bytes(),
        truth: truth_score,
    })
}
