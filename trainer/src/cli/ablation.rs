//! `s3tir-train ablation`: the TGA-GS ablation's four runs at equal iterations and at equal
//! time (`--study tga`) or the S³-TIR ablation's six (`--study spectral`), and their tables.

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
    let a = a.train;
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
                "{} iterations per run (RGB pre-training {}), then every variant at the joint \
                 run's training time",
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
    use s3tir_trainer::ablation::{self, Equal, SpectralVariant, spectral};
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    // Progress per run, in thousandths: iterations of `iters` or seconds of the run's budget.
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {percent:>3}% {msg} [{elapsed_precise}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let show = |index: usize, planned: usize, budget_s: Option<f64>, slug: &str, e: &Event| {
        if let Event::Step {
            iteration, seconds, ..
        } = e
        {
            let done = match budget_s {
                Some(b) => seconds / b.max(1e-9),
                None => *iteration as f64 / base.iters.max(1) as f64,
            };
            bar.set_length(planned as u64 * 1000);
            bar.set_position(index as u64 * 1000 + (done.clamp(0.0, 1.0) * 1000.0) as u64);
            bar.set_message(format!("{slug} ({} of {planned})", index + 1));
        }
    };
    let context = || format!("the ablation in {}", out.display());
    let (table, json) = match study {
        Study::Tga => {
            let rows = ablation::run_ablation(base, out, backend, &stop, &mut |l, e| {
                let slug = match l.equal {
                    Equal::Iterations => l.variant.slug().to_owned(),
                    Equal::Time => format!("{} at equal time", l.variant.slug()),
                };
                show(l.index, l.planned, l.budget_s, &slug, e);
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
                show(
                    k,
                    SpectralVariant::ALL.len(),
                    base.time_budget_s,
                    v.slug(),
                    e,
                );
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
