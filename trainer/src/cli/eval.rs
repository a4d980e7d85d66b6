//! `s3tir-train eval`: a run's held-out views scored (PSNR, SSIM, LPIPS, kelvin), or (`--truth`) the
//! run scored against its dataset's truth.

use std::path::{Path, PathBuf};

#[cfg(not(feature = "vulkan"))]
use anyhow::bail;
use anyhow::{Context, Result};
use clap::Args;
use s3tir_trainer::train::{self, BackendKind, CpuBackend};

/// Options of `s3tir-train eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run folder written by training.
    pub run_dir: PathBuf,
    /// Print one JSON object (`psnr`, `ssim`, `kelvin_mae` (null when not radiometric),
    /// `kelvin_rmse`, the aligned `psnr_aligned` and `kelvin_mae_aligned`, `lpips` (absent
    /// without the LPIPS weights: scripts/install-lpips.py), `primitives`, `views`, `backend`).
    #[arg(long)]
    pub json: bool,
    /// Backend that renders the held-out views: `cpu` (the reference renderer) or `vulkan`
    /// (the backend runs train on; renders agree with the CPU's to float noise).
    #[arg(long, value_enum, default_value_t = BackendKind::Cpu)]
    pub backend: BackendKind,
    /// Vulkan device index (see `devices`; default: the best device).
    #[arg(long)]
    pub device_index: Option<usize>,
    /// Also score the run against its dataset's truth (a simulated joint scene's
    /// DATA/truth: thermal at the input resolution and super-resolved at K× against
    /// bicubic upsampling, RGB, depth).
    #[arg(long)]
    pub truth: bool,
}

/// `eval`: the held-out evaluation, or the truth score with `--truth`.
pub fn run(a: &EvalArgs) -> Result<()> {
    if a.truth {
        truth_cmd(&a.run_dir, a.json)
    } else {
        eval_cmd(&a.run_dir, a.json, a.backend, a.device_index)
    }
}

fn eval_cmd(
    run_dir: &Path,
    json: bool,
    backend: BackendKind,
    device_index: Option<usize>,
) -> Result<()> {
    let run = evaluate_on(run_dir, backend, device_index)?;
    let e = &run.eval;
    if json {
        let mut v = serde_json::to_value(&run)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("view_count".into(), e.views.len().into());
            o.insert("backend".into(), backend.as_str().into());
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let k = |x: Option<f64>| x.map_or_else(|| "—".to_owned(), |v| format!("{v:.3} K"));
    let db = |x: Option<f64>| x.map_or_else(|| "—".to_owned(), |v| format!("{v:6.2} dB"));
    let lp = |x: Option<f64>| x.map_or_else(|| "—".to_owned(), |v| format!("{v:.4}"));
    println!(
        "raw: the render as it is; aligned: under the view's fitted affine map (PSNR) or median offset (MAE)"
    );
    for v in &e.views {
        println!(
            "{:<24} PSNR {:6.2} dB (aligned {})  SSIM {:.4}  LPIPS {}  MAE {} (aligned {})  RMSE {}",
            v.name,
            v.psnr,
            db(v.psnr_aligned),
            v.ssim,
            lp(v.lpips),
            k(v.kelvin_mae),
            k(v.kelvin_mae_aligned),
            k(v.kelvin_rmse)
        );
    }
    println!(
        "{:<24} PSNR {:6.2} dB (aligned {})  SSIM {:.4}  LPIPS {}  MAE {} (aligned {})  RMSE {}  ({} views, {} primitives, mode {})",
        "mean",
        e.psnr,
        db(e.psnr_aligned),
        e.ssim,
        lp(e.lpips),
        k(e.kelvin_mae),
        k(e.kelvin_mae_aligned),
        k(e.kelvin_rmse),
        e.views.len(),
        run.primitives,
        run.mode
    );
    println!("rendered on the {backend} backend");
    Ok(())
}

/// The held-out evaluation of `run_dir` on `backend` (`cpu` or `vulkan`).
fn evaluate_on(
    run_dir: &Path,
    backend: BackendKind,
    device_index: Option<usize>,
) -> Result<train::RunEval> {
    let what = || format!("evaluating {} on the {backend} backend", run_dir.display());
    // A bar over the held-out views (indicatif draws it only when stderr is a terminal).
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("evaluating [{bar:30}] {pos}/{len} views")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let mut on_view = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let run = match backend {
        #[cfg(feature = "vulkan")]
        BackendKind::Vulkan => {
            let b = s3tir_trainer::gpu::backend::VulkanBackend::new(
                &super::vulkan_options(device_index, false),
                s3tir_trainer::render::RenderSettings::default(),
            )
            .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
            train::evaluate_run_with(run_dir, b, &mut on_view).with_context(what)
        }
        #[cfg(not(feature = "vulkan"))]
        BackendKind::Vulkan => {
            let _ = device_index;
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        BackendKind::Cpu => train::evaluate_run_with(run_dir, CpuBackend::default(), &mut on_view)
            .with_context(what),
    };
    bar.finish_and_clear();
    run
}

/// `eval --truth`: the run scored against its dataset's truth.
fn truth_cmd(run_dir: &Path, json: bool) -> Result<()> {
    let s = s3tir_trainer::truth::score_run(run_dir, CpuBackend::default())
        .with_context(|| format!("scoring {} against its dataset's truth", run_dir.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    let t = |x: &s3tir_trainer::truth::ThermalScore| {
        format!(
            "PSNR {:6.2} dB  SSIM {:.4}  MAE {:.3} K",
            x.psnr, x.ssim, x.kelvin_mae
        )
    };
    println!(
        "{} held-out instants, super-resolution {}×",
        s.views, s.scale
    );
    println!("thermal, input resolution:      {}", t(&s.thermal));
    println!(
        "thermal, rendered at {}×:        {}",
        s.scale,
        t(&s.thermal_sr)
    );
    println!(
        "thermal, bicubic {}× of input:   {}",
        s.scale,
        t(&s.bicubic_sr)
    );
    println!(
        "thermal, {}× fused with input:   {}  (renders_sr_fused/: the render back-projected onto the recorded image)",
        s.scale,
        t(&s.fused_sr)
    );
    if let Some(bb) = &s.bicubic_bp_sr {
        println!(
            "thermal, bicubic {}× fused:      {}  (the control: the same back-projection from bicubic, no model)",
            s.scale,
            t(bb)
        );
    }
    if let (Some(p), Some(q)) = (s.rgb_psnr, s.rgb_ssim) {
        println!("RGB:                            PSNR {p:6.2} dB  SSIM {q:.4}");
    }
    for (what, d) in [
        ("RGB cameras", s.depth_rgb),
        ("thermal cameras", s.depth_thermal),
    ] {
        println!(
            "depth at the {what}: MAE {:.1} mm over {:.0} % of the true surface",
            d.mae_m * 1000.0,
            d.coverage * 100.0
        );
    }
    Ok(())
}
