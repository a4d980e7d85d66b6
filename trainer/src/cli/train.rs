//! `s3tir-train DATA --out RUN_DIR` / `train`: a new or resumed run, with a progress bar and
//! Ctrl-C handling.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use s3tir_trainer::dataset::Dataset;
use s3tir_trainer::train::{
    self, Backend, BackendKind, CpuBackend, Event, Outcome, TrainConfig, Trainer,
};

#[cfg(feature = "session")]
use super::session::pose_session;

use super::train_args::{BackendChoice, TrainArgs, new_config};
use super::train_summary;

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
    } else if !a.resume && image_folder(&data) {
        folder_dataset(&a, &data, &out)?
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
        if let Some(b) = a.backend.and_then(BackendChoice::kind)
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
    // `auto` for a new run unless --backend names one, and on --resume only when asked for.
    let auto = match a.backend {
        Some(choice) => choice == BackendChoice::Auto,
        None => !a.resume,
    };
    if auto {
        return train_auto(cfg, dataset, &out, &a);
    }
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

/// `--backend auto` ([`super::open_auto`]): the best Vulkan device when one opens and passes
/// the trainer's checks, else the CPU; says which and why, and the run's config.json keeps the
/// backend it got.
fn train_auto(mut cfg: TrainConfig, dataset: Dataset, out: &Path, a: &TrainArgs) -> Result<()> {
    #[cfg(feature = "vulkan")]
    let why = match super::open_auto(a.device_index, a.no_float_atomics) {
        Ok((backend, why)) => {
            cfg.backend = BackendKind::Vulkan;
            say!(
                a.json,
                "training on the vulkan backend (--backend auto: {why})"
            );
            return run_training(cfg, dataset, backend, out, a.resume, a.json);
        }
        Err(why) => why,
    };
    #[cfg(not(feature = "vulkan"))]
    let why = super::auto_backend(a.device_index, a.no_float_atomics).1;
    cfg.backend = BackendKind::Cpu;
    say!(
        a.json,
        "training on the cpu backend (--backend auto: {why})"
    );
    run_training(cfg, dataset, CpuBackend::default(), out, a.resume, a.json)
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

/// Whether DATA is a folder of images to pose (feature `session`).
#[cfg(feature = "session")]
fn image_folder(data: &Path) -> bool {
    super::session::is_image_folder(data)
}

#[cfg(not(feature = "session"))]
fn image_folder(_: &Path) -> bool {
    false
}

/// `s3tir-train IMAGES_DIR`: the posed dataset (feature `session`).
#[cfg(feature = "session")]
fn folder_dataset(a: &TrainArgs, dir: &Path, out: &Path) -> Result<std::path::PathBuf> {
    super::session::pose_folder(a, dir, out)
}

#[cfg(not(feature = "session"))]
fn folder_dataset(_: &TrainArgs, dir: &Path, _: &Path) -> Result<std::path::PathBuf> {
    bail!(
        "{} is a folder of images, but this s3tir-train was built without the `session` feature: pose it with `s3tir-calib poses {}`",
        dir.display(),
        dir.display()
    )
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

/// The training loop on any backend, with a progress bar and Ctrl-C handling; the outcome is
/// reported by [`super::train_summary`] (Ctrl-C: exit status 130 after the checkpoint).
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
    let stop = stop_on_ctrl_c()?;
    let wall = std::time::Instant::now();
    let mut progress = TrainProgress::new(&trainer);
    let outcome = trainer.run(&stop, &mut |e| progress.event(e))?;
    progress.bar.finish();
    match outcome {
        Outcome::Interrupted { iteration } => {
            train_summary::interrupted(&trainer, out, iteration, json);
            std::process::exit(130);
        }
        Outcome::Finished => {
            // The outputs are on disk: a report that cannot be drawn is a warning, not a
            // failed run.
            let report =
                super::report::write_report_after_training(out, &trainer.cfg, &trainer.data)
                    .map_err(|e| eprintln!("warning: no run report: {e:#}"))
                    .ok();
            train_summary::finished(&trainer, out, wall, json, report.as_deref());
            Ok(())
        }
    }
}

/// A flag Ctrl-C sets; the loop checkpoints and stops at the next step.
fn stop_on_ctrl_c() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    Ok(stop)
}

/// The progress bar of a run: training seconds with a time budget, else iterations; its
/// message shows the smoothed loss, the last held-out PSNR and the primitive count.
struct TrainProgress {
    bar: indicatif::ProgressBar,
    budget: Option<f64>,
    psnr: f64,
    loss_ema: f64,
    prims: usize,
}

impl TrainProgress {
    fn new<B: Backend>(trainer: &Trainer<B>) -> Self {
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
        let progress = Self {
            bar,
            budget,
            psnr: f64::NAN,
            loss_ema: f64::NAN,
            prims: trainer.prims.len(),
        };
        progress
            .bar
            .set_position(progress.position(trainer.iteration, trainer.train_seconds));
        progress
    }

    fn position(&self, iteration: u64, seconds: f64) -> u64 {
        match self.budget {
            Some(_) => seconds as u64,
            None => iteration,
        }
    }

    fn event(&mut self, e: &Event) {
        match e {
            Event::Step {
                iteration,
                loss,
                seconds,
                primitives,
            } => {
                self.loss_ema = if self.loss_ema.is_nan() {
                    *loss
                } else {
                    0.95 * self.loss_ema + 0.05 * loss
                };
                self.prims = *primitives;
                self.bar.set_position(self.position(*iteration, *seconds));
                if iteration % 10 == 0 {
                    self.bar.set_message(format!(
                        "it {iteration}  loss {:.4}  held-out PSNR {:.2} dB  {} primitives",
                        self.loss_ema, self.psnr, self.prims
                    ));
                }
            }
            Event::Eval(row) => {
                self.psnr = row.psnr;
                self.bar.set_message(format!(
                    "loss {:.4}  held-out PSNR {:.2} dB  {} primitives",
                    self.loss_ema, self.psnr, self.prims
                ));
            }
            Event::Checkpoint { .. } => {}
        }
    }
}
