//! `s3tir-train ablation`: the TGA-GS ablation's four runs and their table.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use s3tir_trainer::train::{self, Backend, BackendKind, CpuBackend, Event, TrainConfig};

use super::train_args::{TrainArgs, new_config};

/// `s3tir-train ablation`: the four runs and their table.
pub fn run(mut a: TrainArgs) -> Result<()> {
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
    a.rgb_pretrain = Some(a.rgb_pretrain.unwrap_or(iters / 10));
    let base = new_config(&a, data)?;
    println!(
        "ablation of {} into {}: {} iterations per run, RGB pre-training {}, {} backend",
        base.data.display(),
        out.display(),
        base.iters,
        base.joint.rgb_pretrain,
        base.backend
    );
    match base.backend {
        #[cfg(feature = "vulkan")]
        BackendKind::Vulkan => {
            let opts = super::vulkan_options(a.device_index, a.no_float_atomics);
            ablation_on(&base, &out, &mut || {
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
        BackendKind::Cpu => ablation_on(&base, &out, &mut || Ok(CpuBackend::default())),
    }
}

/// The ablation's runs on the backend `backend` makes, with a progress bar; writes the table.
fn ablation_on<B: Backend>(
    base: &TrainConfig,
    out: &Path,
    backend: &mut dyn FnMut() -> std::result::Result<B, train::TrainError>,
) -> Result<()> {
    use s3tir_trainer::ablation::{self, Variant};
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    let bar = indicatif::ProgressBar::new(base.iters * Variant::ALL.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} it {msg} [{elapsed_precise}]",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let runs = Variant::ALL.len() as u64;
    let iters_per_run = base.iters;
    let rows = ablation::run_ablation(base, out, backend, &stop, &mut |v, e| {
        if let Event::Step { iteration, .. } = e {
            let k = Variant::ALL.iter().position(|x| *x == v).unwrap_or(0) as u64;
            bar.set_position((k * iters_per_run + iteration).min(runs * iters_per_run));
            bar.set_message(v.slug());
        }
    })
    .with_context(|| format!("the ablation in {}", out.display()))?;
    bar.finish_and_clear();
    let table = ablation::markdown(&rows);
    let md = out.join("ablation.md");
    std::fs::write(&md, &table).with_context(|| format!("writing {}", md.display()))?;
    let js = out.join("ablation.json");
    std::fs::write(&js, serde_json::to_string_pretty(&rows)? + "\n")
        .with_context(|| format!("writing {}", js.display()))?;
    print!("{table}");
    println!("written: {} and {}", md.display(), js.display());
    Ok(())
}
