//! `s3tir-train ablation`: the TGA-GS ablation's four runs (`--study tga`) or the S³-TIR
//! ablation's six (`--study spectral`), and their table.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use s3tir_trainer::train::{self, Backend, BackendKind, CpuBackend, Event, TrainConfig};

use super::train_args::{TrainArgs, new_config};

/// Which ablation `s3tir-train ablation` runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum Study {
    /// TGA-GS (joint RGB + thermal) on a dataset with truth.
    #[default]
    Tga,
    /// S³-TIR's Table 2 (β fixed, f = 0, no consistency, no sparsity, 3DGS) on any thermal
    /// dataset.
    Spectral,
}

/// Options of `s3tir-train ablation`: the study, and the training options every run shares.
#[derive(Debug, Args)]
pub struct AblationArgs {
    /// Which ablation.
    #[arg(long, value_enum, default_value_t = Study::default())]
    pub study: Study,
    #[command(flatten)]
    pub train: TrainArgs,
}

/// `s3tir-train ablation`: the runs and their table.
pub fn run(a: AblationArgs) -> Result<()> {
    let study = a.study;
    let mut a = a.train;
    let (Some(data), Some(out)) = (a.data.clone(), a.out.clone()) else {
        bail!("the ablation needs DATA and --out RUN_DIR");
    };
    if a.resume {
        bail!("the ablation does not resume: choose a new --out");
    }
    if out.exists() {
        bail!(
            "{} exists: the ablation never overwrites runs (choose another --out)",
            out.display()
        );
    }
    let data = std::fs::canonicalize(&data)
        .with_context(|| format!("dataset folder {}", data.display()))?;
    let iters = a.iters.unwrap_or(30_000);
    if study == Study::Tga {
        a.rgb_pretrain = Some(a.rgb_pretrain.unwrap_or(iters / 10));
    }
    let mut base = new_config(&a, data)?;
    if a.backend.is_none_or(|b| b.kind().is_none()) {
        let (kind, why) = super::auto_backend(a.device_index, a.no_float_atomics);
        println!("--backend auto: {kind} ({why})");
        base.backend = kind;
    }
    println!(
        "{} ablation of {} into {}: {}, {} backend",
        match study {
            Study::Tga => "TGA-GS",
            Study::Spectral => "S³-TIR",
        },
        base.data.display(),
        out.display(),
        match (base.time_budget_s, study) {
            (Some(s), _) => format!("{s:.0} s of training per run"),
            (None, Study::Tga) => format!(
                "{} iterations per run, RGB pre-training {}",
                base.iters, base.joint.rgb_pretrain
            ),
            (None, Study::Spectral) => format!("{} iterations per run", base.iters),
        },
        base.backend
    );
    match base.backend {
        #[cfg(feature = "vulkan")]
        BackendKind::Vulkan => {
            let opts = super::vulkan_options(a.device_index, a.no_float_atomics);
            ablation_on(study, &base, &out, &mut || {
                s3tir_trainer::gpu::backend::VulkanBackend::new(
                    &opts,
                    s3tir_trainer::render::RenderSettings::default(),
                )
                .map_err(|e| train::TrainError::Render(e.into()))
            })
        }
        #[cfg(not(feature = "vulkan"))]
        BackendKind::Vulkan => {
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        BackendKind::Cpu => ablation_on(study, &base, &out, &mut || Ok(CpuBackend::default())),
    }
}

/// The ablation's runs on the backend `backend` makes, with a progress bar; writes the table.
fn ablation_on<B: Backend>(
    study: Study,
    base: &TrainConfig,
    out: &Path,
    backend: &mut dyn FnMut() -> std::result::Result<B, train::TrainError>,
) -> Result<()> {
    use s3tir_trainer::ablation::{self, SpectralVariant, Variant, spectral};
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    let runs = match study {
        Study::Tga => Variant::ALL.len(),
        Study::Spectral => SpectralVariant::ALL.len(),
    } as u64;
    // Progress in iterations, or with a time budget in training seconds (×10 for resolution).
    let per_run = match base.time_budget_s {
        Some(s) => (s * 10.0).ceil() as u64,
        None => base.iters,
    };
    let bar = indicatif::ProgressBar::new(per_run * runs);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {percent:>3}% {msg} [{elapsed_precise}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let timed = base.time_budget_s.is_some();
    let show = |k: usize, slug: &str, e: &Event| {
        if let Event::Step {
            iteration, seconds, ..
        } = e
        {
            let done = if timed {
                (seconds * 10.0) as u64
            } else {
                *iteration
            };
            bar.set_position((k as u64 * per_run + done.min(per_run)).min(runs * per_run));
            bar.set_message(slug.to_owned());
        }
    };
    let context = || format!("the ablation in {}", out.display());
    let (table, json) = match study {
        Study::Tga => {
            let rows = ablation::run_ablation(base, out, backend, &stop, &mut |v, e| {
                let k = Variant::ALL.iter().position(|x| *x == v).unwrap_or(0);
                show(k, v.slug(), e);
            })
            .with_context(context)?;
            (
                ablation::markdown(&rows),
                serde_json::to_string_pretty(&rows)?,
            )
        }
        Study::Spectral => {
            let rows = spectral::run_spectral_ablation(base, out, backend, &stop, &mut |v, e| {
                let k = SpectralVariant::ALL
                    .iter()
                    .position(|x| *x == v)
                    .unwrap_or(0);
                show(k, v.slug(), e);
            })
            .with_context(context)?;
            (
                spectral::spectral_markdown(&rows),
                serde_json::to_string_pretty(&rows)?,
            )
        }
    };
    bar.finish_and_clear();
    let md = out.join("ablation.md");
    std::fs::write(&md, &table).with_context(|| format!("writing {}", md.display()))?;
    let js = out.join("ablation.json");
    std::fs::write(&js, json + "\n").with_context(|| format!("writing {}", js.display()))?;
    print!("{table}");
    println!("written: {} and {}", md.display(), js.display());
    Ok(())
}
