//! `s3tir-train DATA --out RUN_DIR` / `train`: a new or resumed run, with a progress bar and
//! Ctrl-C handling.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use s3tir_trainer::dataset::Dataset;
use s3tir_trainer::train::{
    self, Backend, BackendKind, CpuBackend, Event, Outcome, TrainConfig, Trainer, files,
};

#[cfg(feature = "session")]
use super::session::pose_session;

/// A human-readable line: on stdout, or on stderr when stdout carries the `--json` summary.
macro_rules! say {
    ($json:expr, $($arg:tt)*) => {
        if $json {
            eprintln!($($arg)*)
        } else {
            println!($($arg)*)
        }
    };
}
use super::train_args::{TrainArgs, new_config};

/// Trains (or with `--resume` continues) the run `a` describes; a recorded session
/// (`.mcap`, feature `session`) is posed into a dataset first.
pub fn run(a: TrainArgs) -> Result<()> {
    let (Some(data), Some(out)) = (a.data.clone(), a.out.clone()) else {
        bail!("training needs DATA and --out RUN_DIR");
    };
    let data = if !a.resume
        && data
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    {
        session_dataset(&a, &data, &out)?
    } else {
        data
    };
    let data = std::fs::canonicalize(&data)
        .with_context(|| format!("dataset folder {}", data.display()))?;
    let cfg = if a.resume {
        let mut cfg = train::load_config(&out)
            .with_context(|| format!("--resume: reading the run in {}", out.display()))?;
        if let Some(n) = a.iters {
            cfg.iters = n;
        }
        if let Some(b) = a.time_budget {
            cfg.time_budget_s = Some(b);
        }
        // The run's own backend unless --backend says otherwise (a flag default used to
        // switch a resumed Vulkan run to the CPU).
        if let Some(b) = a.backend
            && b != cfg.backend
        {
            say!(
                a.json,
                "--resume: switching from the run's {} backend to {b} (--backend)",
                cfg.backend
            );
            cfg.backend = b;
        }
        cfg
    } else {
        new_config(&a, data)?
    };
    // No context added: every dataset error names the file or folder it is about.
    let dataset = Dataset::load(&cfg.data, &cfg.load)?;
    say!(
        a.json,
        "dataset {}: {} views ({} train, {} held out){}",
        cfg.data.display(),
        dataset.views.len(),
        dataset.train.len(),
        dataset.test.len(),
        if dataset.range.is_some_and(|r| r.radiometric()) {
            ", radiometric"
        } else {
            ""
        }
    );
    say!(a.json, "training on the {} backend", cfg.backend);
    match cfg.backend {
        BackendKind::Vulkan => train_vulkan(
            cfg,
            dataset,
            &out,
            a.resume,
            a.device_index,
            a.no_float_atomics,
            a.json,
        ),
        BackendKind::Cpu => {
            run_training(cfg, dataset, CpuBackend::default(), &out, a.resume, a.json)
        }
    }
}

#[cfg(feature = "vulkan")]
fn train_vulkan(
    cfg: TrainConfig,
    dataset: Dataset,
    out: &Path,
    resume: bool,
    device_index: Option<usize>,
    no_float_atomics: bool,
    json: bool,
) -> Result<()> {
    let backend = s3tir_trainer::gpu::backend::VulkanBackend::new(
        &super::vulkan_options(device_index, no_float_atomics),
        s3tir_trainer::render::RenderSettings::default(),
    )
    .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
    run_training(cfg, dataset, backend, out, resume, json)
}

#[cfg(not(feature = "vulkan"))]
fn train_vulkan(
    _: TrainConfig,
    _: Dataset,
    _: &Path,
    _: bool,
    _: Option<usize>,
    _: bool,
    _: bool,
) -> Result<()> {
    bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
}

/// `s3tir-train SESSION.mcap`: the posed dataset (feature `session`).
#[cfg(feature = "session")]
fn session_dataset(a: &TrainArgs, session: &Path, out: &Path) -> Result<std::path::PathBuf> {
    pose_session(a, session, out)
}

/// Without the `session` feature a recorded session is refused with what to do instead.
#[cfg(not(feature = "session"))]
fn session_dataset(_: &TrainArgs, session: &Path, _: &Path) -> Result<std::path::PathBuf> {
    bail!(
        "{} is a recorded session, but this s3tir-train was built without the `session` feature \
         (no MCAP reader or poses stage): pose it with `s3tir-calib poses {}` and train on the \
         dataset it writes, or build s3tir-train with `--features session`",
        session.display(),
        session.display()
    )
}

/// The training loop on any backend, with a progress bar and Ctrl-C handling.
fn run_training<B: Backend>(
    cfg: TrainConfig,
    dataset: Dataset,
    backend: B,
    out: &Path,
    resume: bool,
    json: bool,
) -> Result<()> {
    let mut trainer = if resume {
        Trainer::resume(cfg, dataset, backend, out)?
    } else {
        Trainer::new(cfg, dataset, backend, out)?
    };

    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    // With a time budget the bar counts training seconds, else iterations.
    let budget = trainer.cfg.time_budget_s;
    let (len, unit) = match budget {
        Some(b) => (b.ceil() as u64, "s"),
        None => (trainer.cfg.iters, "it"),
    };
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{bar:30}}] {{pos}}/{{len}} {unit}  {{msg}}"
        ))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let position = |iteration: u64, seconds: f64| match budget {
        Some(_) => seconds as u64,
        None => iteration,
    };
    bar.set_position(position(trainer.iteration, trainer.train_seconds));
    let wall = std::time::Instant::now();
    let mut psnr = f64::NAN;
    let mut loss_ema = f64::NAN;
    let mut prims = trainer.prims.len();
    let outcome = trainer.run(&stop, &mut |e| match e {
        Event::Step {
            iteration,
            loss,
            seconds,
            primitives,
        } => {
            loss_ema = if loss_ema.is_nan() {
                *loss
            } else {
                0.95 * loss_ema + 0.05 * loss
            };
            prims = *primitives;
            bar.set_position(position(*iteration, *seconds));
            if iteration % 10 == 0 {
                bar.set_message(format!(
                    "it {iteration}  loss {loss_ema:.4}  held-out PSNR {psnr:.2} dB  {prims} primitives"
                ));
            }
        }
        Event::Eval(row) => {
            psnr = row.psnr;
            bar.set_message(format!(
                "loss {loss_ema:.4}  held-out PSNR {psnr:.2} dB  {prims} primitives"
            ));
        }
        Event::Checkpoint { .. } => {}
    })?;
    bar.finish();
    match outcome {
        Outcome::Interrupted { iteration } => {
            if json {
                println!(
                    "{}",
                    serde_json::json!({
                        "outcome": "interrupted",
                        "out": out,
                        "iterations": iteration,
                        "train_seconds": trainer.train_seconds,
                        "checkpoint": out.join(files::CHECKPOINT),
                    })
                );
            }
            say!(
                json,
                "interrupted at iteration {iteration}: checkpoint written to {}; continue with --resume",
                out.join(files::CHECKPOINT).display()
            );
            std::process::exit(130);
        }
        Outcome::Finished => {
            let cap = trainer.capacity_report();
            say!(
                json,
                "done: {} primitives in {}",
                trainer.prims.len(),
                out.display()
            );
            let written: Vec<std::path::PathBuf> = [
                files::PLY,
                files::METRICS_CSV,
                files::METRICS_PNG,
                files::EVAL,
                files::CAPACITY,
                files::BETA_HIST,
                files::RENDERS,
                files::RENDERS_SR,
                files::GBUFFERS,
            ]
            .iter()
            .map(|f| out.join(f))
            .filter(|p| p.exists())
            .collect();
            for p in &written {
                say!(json, "  {}", p.display());
            }
            say!(
                json,
                "left out: colour {}; consistency: {}; bands {} → {} ({} bytes saved); {} primitives on the Gaussian path; view response: {}",
                if cap.colour_allocated {
                    "kept"
                } else {
                    "not allocated"
                },
                cap.consistency_reason,
                cap.bands_initial,
                cap.bands_now,
                cap.band_bytes_saved,
                cap.gaussian_path_primitives,
                cap.response.as_ref().map_or("none", |r| r.kind.as_str())
            );
            if let Some(r) = &cap.response {
                say!(json, "view response: {}", r.describe());
            }
            if let Some(why) = &cap.rgb_loss {
                say!(
                    json,
                    "joint RGB + thermal: RGB loss {why}; thermal gradient alignment {}; {}",
                    if cap.thermal_align > 0.0 {
                        format!("weight {}", cap.thermal_align)
                    } else {
                        "off".into()
                    },
                    if trainer.cfg.joint.pair_steps {
                        "each step trains a view with the other camera's image of its instant"
                    } else {
                        "each step trains one view (--no-pair-steps)"
                    }
                );
            }
            say!(
                json,
                "density control: {} rounds, {} cloned, {} split, {} pruned, {} relocated; {} primitives at the end (budget {})",
                cap.densify_rounds.len(),
                cap.densify_cloned,
                cap.densify_split,
                cap.densify_pruned,
                cap.densify_relocated,
                cap.primitives,
                trainer.cfg.budget
            );
            if let Some(b) = budget {
                say!(
                    json,
                    "time budget: {:.1} s of training time of {b:.1} s ({} iterations); {:.1} s wall clock with evaluations, checkpoints and outputs",
                    trainer.train_seconds,
                    trainer.iteration,
                    wall.elapsed().as_secs_f64()
                );
            }
            if json {
                // The held-out figures as `eval` wrote them (absent when nothing is held out).
                let eval: Option<serde_json::Value> = std::fs::read(out.join(files::EVAL))
                    .ok()
                    .and_then(|b| serde_json::from_slice(&b).ok());
                println!(
                    "{}",
                    serde_json::json!({
                        "outcome": "finished",
                        "out": out,
                        "backend": trainer.cfg.backend,
                        "iterations": trainer.iteration,
                        "train_seconds": trainer.train_seconds,
                        "wall_seconds": wall.elapsed().as_secs_f64(),
                        "primitives": cap.primitives,
                        "budget": trainer.cfg.budget,
                        "density_control": {
                            "rounds": cap.densify_rounds.len(),
                            "cloned": cap.densify_cloned,
                            "split": cap.densify_split,
                            "pruned": cap.densify_pruned,
                            "relocated": cap.densify_relocated,
                        },
                        "eval": eval,
                        "files": written,
                    })
                );
            }
            Ok(())
        }
    }
}
