//! `s3tir-train bench --mesh`: seconds per stage and peak memory of meshing a realistic scene —
//! by default 100 views at 640×512 (a Lepton 3.5 / Boson 640 session) of the synthetic wall
//! scene with 30 000 primitives initialised from its sparse points and made opaque (as
//! training leaves a surface) — on the CPU backend.
//! The render of the views is the reference the other stages are given against (a ratio in
//! the same process, on this machine).

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::error::MeshError;
use super::run::{MeshOptions, MeshStage, MeshStats, mesh_views, peak_rss_bytes};
use crate::dataset::synth::{self, SynthConfig};
use crate::dataset::{Dataset, LoadOptions};
use crate::train::{CpuBackend, TrainConfig, TrainError, Trainer};

/// What to mesh.
#[derive(Debug, Clone)]
pub struct MeshBenchOptions {
    pub width: usize,
    pub height: usize,
    pub views: usize,
    pub primitives: usize,
    pub mesh: MeshOptions,
}

impl Default for MeshBenchOptions {
    fn default() -> Self {
        Self {
            width: 640,
            height: 512,
            views: 100,
            primitives: 30_000,
            mesh: MeshOptions::default(),
        }
    }
}

/// The figures.
#[derive(Debug, Clone, Serialize)]
pub struct MeshBenchReport {
    pub width: usize,
    pub height: usize,
    pub primitives: usize,
    #[serde(flatten)]
    pub stats: MeshStats,
    /// Render + fuse + extract, seconds.
    pub seconds: f64,
    /// Fusion (sizing included) and extraction over the render of the views.
    pub fuse_over_render: f64,
    pub extract_over_render: f64,
    /// Peak resident memory of the process before meshing (scene and model loaded) and after.
    pub rss_before_bytes: Option<u64>,
    pub peak_rss_bytes: Option<u64>,
    pub threads: usize,
}

/// Writes the scene into a temporary folder, meshes it, removes the folder.
pub fn run(
    opts: &MeshBenchOptions,
    progress: &mut dyn FnMut(MeshStage, usize, usize),
    log: &mut dyn FnMut(&str),
) -> Result<MeshBenchReport, MeshError> {
    let root = std::env::temp_dir().join(format!("s3tir-mesh-bench-{}", std::process::id()));
    let result = run_in(&root, opts, progress, log);
    let _ = std::fs::remove_dir_all(&root);
    result
}

fn run_in(
    root: &Path,
    opts: &MeshBenchOptions,
    progress: &mut dyn FnMut(MeshStage, usize, usize),
    log: &mut dyn FnMut(&str),
) -> Result<MeshBenchReport, MeshError> {
    let data_dir = root.join("scene");
    let scene = SynthConfig::bench(opts.width, opts.height, opts.views, opts.primitives);
    log(&format!(
        "scene: {} views of {}x{}, {} primitives",
        opts.views, opts.width, opts.height, opts.primitives
    ));
    synth::write_scene(&data_dir, &scene).map_err(TrainError::from)?;
    let data = Dataset::load(&data_dir, &LoadOptions::default()).map_err(TrainError::from)?;
    let range = data.range.ok_or_else(|| MeshError::Run {
        reason: "the synthetic scene has no thermal range".into(),
    })?;
    let cameras: Vec<_> = data.views.iter().map(|v| v.camera).collect();
    let mut cfg = TrainConfig::new(data_dir.clone());
    cfg.budget = opts.primitives;
    cfg.seed = 1;
    let trainer = Trainer::new(cfg, data, CpuBackend::default(), &root.join("run"))?;
    // Initialised primitives start at opacity 0.1 (3DGS's start); a trained surface is opaque.
    let mut prims = trainer.prims;
    prims.opacity_logits.iter_mut().for_each(|o| *o = 4.0);
    let rss_before_bytes = peak_rss_bytes();
    log(&format!("meshing {} views", cameras.len()));
    let t = Instant::now();
    let (_, stats) = mesh_views(
        &prims,
        &cameras,
        &range,
        &opts.mesh,
        &mut CpuBackend::default(),
        progress,
    )?;
    let seconds = t.elapsed().as_secs_f64();
    let render = stats.render_s.max(1e-9);
    Ok(MeshBenchReport {
        width: opts.width,
        height: opts.height,
        primitives: prims.len(),
        fuse_over_render: stats.fuse_s / render,
        extract_over_render: stats.extract_s / render,
        stats,
        seconds,
        rss_before_bytes,
        peak_rss_bytes: peak_rss_bytes(),
        threads: rayon::current_num_threads(),
    })
}
