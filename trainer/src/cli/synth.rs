//! `s3tir-train synth`: the built-in analytic test scene written as a COLMAP dataset.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

/// Options of `s3tir-train synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Output dataset folder.
    pub out: PathBuf,
    /// Number of views.
    #[arg(long, default_value_t = 16)]
    pub views: usize,
    #[arg(long, default_value_t = 48)]
    pub width: usize,
    #[arg(long, default_value_t = 36)]
    pub height: usize,
}

/// `synth`: writes the scene.
pub fn run(a: &SynthArgs) -> Result<()> {
    let (out, views, width, height) = (&a.out, a.views, a.width, a.height);
    let cfg = s3tir_trainer::dataset::synth::SynthConfig {
        views,
        width,
        height,
        f_px: 40.0 * width as f64 / 48.0,
        ..Default::default()
    };
    s3tir_trainer::dataset::synth::write_scene(out, &cfg)
        .with_context(|| format!("writing the synthetic scene to {}", out.display()))?;
    println!("synthetic scene written to {}", out.display());
    Ok(())
}
