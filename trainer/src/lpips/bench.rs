//! `s3tir-train bench --lpips`: what LPIPS adds to an evaluation, as ratios to the CPU render of
//! the same views in the same process — by default 12 views at 640×512 (a Lepton 3.5 / Boson
//! 640 frame) of the synthetic wall scene with 30 000 primitives.
//!
//! An evaluation runs the network on each render, and on each recorded frame once per run (the
//! frames' features are kept, [`super::FrameFeatures`]); the figures give both.

use std::time::Instant;

use serde::Serialize;

use super::{FrameFeatures, Lpips};
use crate::dataset::synth::{self, SynthConfig};
use crate::dataset::{Dataset, LoadOptions};
use crate::train::{Backend, CpuBackend, TrainConfig, TrainError, Trainer};

/// The figures (milliseconds per view).
#[derive(Debug, Clone, Serialize)]
pub struct LpipsBenchReport {
    pub width: usize,
    pub height: usize,
    pub views: usize,
    pub primitives: usize,
    /// The CPU reference renderer, one view.
    pub render_ms: f64,
    /// LPIPS of a render against a frame seen for the first time (the network on both).
    pub lpips_first_ms: f64,
    /// LPIPS of a render against a frame whose features are kept (every later evaluation).
    pub lpips_cached_ms: f64,
    pub first_over_render: f64,
    pub cached_over_render: f64,
    pub threads: usize,
}

/// Writes the scene into a temporary folder, times the views, removes the folder.
pub fn run(
    lpips: &Lpips,
    (width, height, views, primitives): (usize, usize, usize, usize),
    log: &mut dyn FnMut(&str),
) -> Result<LpipsBenchReport, TrainError> {
    let root = std::env::temp_dir().join(format!("s3tir-lpips-bench-{}", std::process::id()));
    let result = run_in(&root, lpips, (width, height, views, primitives), log);
    let _ = std::fs::remove_dir_all(&root);
    result
}

fn run_in(
    root: &std::path::Path,
    lpips: &Lpips,
    (width, height, views, primitives): (usize, usize, usize, usize),
    log: &mut dyn FnMut(&str),
) -> Result<LpipsBenchReport, TrainError> {
    let data_dir = root.join("scene");
    log(&format!(
        "scene: {views} views of {width}x{height}, {primitives} primitives"
    ));
    synth::write_scene(
        &data_dir,
        &SynthConfig::bench(width, height, views, primitives),
    )?;
    let data = Dataset::load(&data_dir, &LoadOptions::default())?;
    let mut cfg = TrainConfig::new(data_dir.clone());
    cfg.budget = primitives;
    let mut t = Trainer::new(cfg, data, CpuBackend::default(), &root.join("run"))?;
    let ids: Vec<usize> = (0..t.data.views.len())
        .filter(|&i| t.data.views[i].thermal.is_some())
        .collect();
    let (mut render_s, mut first_s, mut cached_s) = (0.0, 0.0, 0.0);
    let mut frames = FrameFeatures::default();
    for &i in &ids {
        let cam = t.data.views[i].camera;
        let c = Instant::now();
        let gb = t.backend.render(&t.prims, &cam)?;
        render_s += c.elapsed().as_secs_f64();
        let Some(frame) = t.data.views[i].thermal.as_deref() else {
            continue;
        };
        let size = (gb.width, gb.height);
        for seconds in [&mut first_s, &mut cached_s] {
            let c = Instant::now();
            let d = frames.plane_lpips(lpips, i, &gb.thermal, frame, size);
            *seconds += c.elapsed().as_secs_f64();
            if d.is_none() {
                return Err(TrainError::Config {
                    reason: format!("{width}x{height} is under LPIPS's {} px", super::MIN_SIDE),
                });
            }
        }
    }
    let n = ids.len().max(1) as f64;
    let ms = |s: f64| 1e3 * s / n;
    Ok(LpipsBenchReport {
        width,
        height,
        views: ids.len(),
        primitives: t.prims.len(),
        render_ms: ms(render_s),
        lpips_first_ms: ms(first_s),
        lpips_cached_ms: ms(cached_s),
        first_over_render: first_s / render_s.max(1e-9),
        cached_over_render: cached_s / render_s.max(1e-9),
        threads: rayon::current_num_threads(),
    })
}
