//! `s3tir-train`: S³-TIR thermal splatting on the rig.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use s3tir_trainer::dataset::images::ColourMode;
use s3tir_trainer::dataset::{Dataset, LoadOptions, Modality, ThermalUnits};
use s3tir_trainer::report;
use s3tir_trainer::train::{
    self, Backend, ConsistPartner, CpuBackend, Densify, Event, Joint, Mode, Outcome,
    ResponseConfig, ResponseKind, RgbLoss, TrainConfig, Trainer, files,
};

/// S³-TIR thermal splatting: fit spatial-spectral primitives to posed thermal (and RGB) frames
/// with a Vulkan compute trainer that runs on the rig, and render novel views.
///
/// Train: `s3tir-train DATA --out RUN_DIR [--mode s3tir|3dgs|ges|gabor] [--iters N]
/// [--backend cpu|vulkan] [--budget N] [--seed S]` (or `s3tir-train train DATA …`). DATA is a
/// COLMAP dataset (`sparse/0/` + `images/`), e.g. the output of `s3tir-firmware-sim scene`.
/// Ctrl-C writes a checkpoint and exits; `--resume` continues from it.
///
/// Joint RGB + thermal (TGA-GS) on a rig's pair of cameras: a dataset holding both cameras'
/// images, each with its own camera (`s3tir-calib poses SESSION --with-rgb`, or
/// `s3tir-train SESSION.mcap --with-rgb`), trains one model with a thermal and a colour head:
/// `s3tir-train DATA --out RUN --rgb-pretrain 3000` — RGB pre-training, then every step trains
/// a view with the other camera's image of the same instant; L1-low for dark RGB
/// (`--rgb-loss auto`), the thermal gradient alignment loss (`--thermal-align`), the thermal
/// head rendered at the RGB resolution into `renders_sr/`. `ablation` measures the variants on
/// a simulated joint scene (`s3tir-firmware-sim scene --rgb-scale 4 --low-light`).
///
/// `mesh RUN --out mesh.ply` fuses a run's rendered depth and temperature into a surface mesh
/// with a float `kelvin` per vertex (binary PLY) and an ironbow-coloured copy.
///
/// `devices` lists the Vulkan devices this computer offers and what the trainer needs of them
/// (storage-buffer range, shared memory, subgroups, float atomics).
#[derive(Debug, Parser)]
#[command(
    name = "s3tir-train",
    version,
    about,
    long_about,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    train: Option<TrainArgs>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List Vulkan devices: name, driver, API version, memory heaps, max storage-buffer range,
    /// shared memory, subgroup size and operations, float-atomic support. Exits non-zero with
    /// the reason when no Vulkan loader or driver is present.
    Devices {
        /// Print one JSON array instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Train a model (same as `s3tir-train DATA --out RUN_DIR …`).
    Train(Box<TrainArgs>),
    /// Benchmark training steps/s: Vulkan backend vs CPU backend on the same scene and budget,
    /// full s3tir mode vs 3dgs mode, and the GPU time per kernel (timestamp queries).
    Bench(BenchArgs),
    /// Evaluate a run on its held-out views: PSNR, SSIM and (radiometric data) kelvin MAE/RMSE,
    /// per view and mean.
    Eval {
        /// Run folder written by training.
        run_dir: PathBuf,
        /// Print one JSON object (`psnr`, `ssim`, `kelvin_mae` (null when not radiometric),
        /// `kelvin_rmse`, the aligned `psnr_aligned` and `kelvin_mae_aligned`, `primitives`,
        /// `views`, `backend`).
        #[arg(long)]
        json: bool,
        /// Backend that renders the held-out views: `cpu` (the reference renderer) or `vulkan`
        /// (the backend runs train on; renders agree with the CPU's to float noise).
        #[arg(long, value_parser = ["cpu", "vulkan"], default_value = "cpu")]
        backend: String,
        /// Vulkan device index (see `devices`; default: the best device).
        #[arg(long)]
        device_index: Option<usize>,
        /// Also score the run against its dataset's truth (a simulated joint scene's
        /// DATA/truth: thermal at the input resolution and super-resolved at K× against
        /// bicubic upsampling, RGB, depth).
        #[arg(long)]
        truth: bool,
    },
    /// The TGA-GS ablation on a dataset with truth (`s3tir-firmware-sim scene --rgb-scale K`):
    /// four runs with the training options given — thermal-only, joint, joint without the
    /// thermal gradient alignment loss, joint without RGB pre-training — into
    /// RUN_DIR/<variant>/, each scored against DATA/truth (thermal at the input resolution and
    /// super-resolved at K× against bicubic upsampling and fused with the recorded image, RGB,
    /// depth) and, when the scene has a truth surface, meshed and the mesh scored (Chamfer,
    /// F-score, vertex kelvin); the table in RUN_DIR/ablation.md and ablation.json. Either
    /// backend (`--backend`).
    Ablation(Box<TrainArgs>),
    /// A surface mesh with a temperature per vertex: the run's training views rendered
    /// (expected depth, kelvin, colour), fused into a sparse truncated signed-distance volume
    /// and extracted by surface nets, trimmed to where the views saw it. Writes OUT (binary
    /// PLY: float `kelvin` per vertex, the run's RGB when it has colour) and OUT_thermal.ply
    /// (coloured by the ironbow palette for viewers that show only RGB); opens in MeshLab,
    /// Blender, CloudCompare. The voxel follows the scene's extent and --memory-budget-mib.
    Mesh(MeshArgs),
    /// Overlay the error-vs-time curves of several runs on one plot (e.g. s3tir vs 3dgs).
    Compare {
        /// Run folders.
        #[arg(required = true)]
        runs: Vec<PathBuf>,
        /// Output PNG.
        #[arg(long, default_value = "compare.png")]
        out: PathBuf,
    },
    /// Write the built-in analytic test scene (a wall with a sharp emissivity step and a heated
    /// pipe) as a COLMAP dataset with 16-bit centikelvin images.
    Synth {
        /// Output dataset folder.
        out: PathBuf,
        /// Number of views.
        #[arg(long, default_value_t = 16)]
        views: usize,
        #[arg(long, default_value_t = 48)]
        width: usize,
        #[arg(long, default_value_t = 36)]
        height: usize,
    },
}

/// Training options. Defaults are the paper's (§4.1); see the trainer's `train` module docs.
#[derive(Debug, Args)]
struct TrainArgs {
    /// Dataset folder (COLMAP `sparse/0/` or `sparse/` + `images/`), or a session recorded by
    /// s3tir-capture (`.mcap`): it is posed first (`s3tir-calib poses`: COLMAP on the RGB
    /// keyframes, thermal poses interpolated and composed with the calibrated extrinsic) into
    /// --dataset, then trained on.
    #[arg(required = true)]
    data: Option<PathBuf>,
    /// Session input: the rig's calibration.yaml [default: the one attached to the session].
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Session input: where to write the posed dataset [default: RUN_DIR-dataset beside the run].
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Session input: the COLMAP program.
    #[arg(long, env = "S3TIR_COLMAP", default_value = "colmap")]
    colmap: PathBuf,
    /// Session input: AprilTag map (see `s3tir-calib poses --help`): metric scale, and poses
    /// without COLMAP where mapped tags are in view.
    #[arg(long)]
    tags: Option<PathBuf>,
    /// Session input: also put the posed RGB keyframes into the dataset (their own camera,
    /// the same world), so the run trains jointly on RGB and thermal (see --views).
    #[arg(long)]
    with_rgb: bool,
    /// Run folder (checkpoint, metrics.csv, plots, PLY, renders and G-buffers of the held-out
    /// views: grey PNGs plus exact f32 `.npy` planes, capacity.json, eval.json).
    #[arg(long, required = true)]
    out: Option<PathBuf>,
    /// s3tir (learnable β + bands), 3dgs (β ≡ 2, no bands), ges (learnable β, no bands),
    /// gabor (bands, β ≡ 2).
    #[arg(long, default_value = "s3tir")]
    mode: Mode,
    /// Iterations [default: 30000; on --resume: the run's own].
    #[arg(long)]
    iters: Option<u64>,
    /// Gaussian warm-up iterations (β ≡ 2, bands off).
    #[arg(long, default_value_t = 3000)]
    warmup: u64,
    /// Compute backend [default: cpu; on --resume: the run's own].
    #[arg(long, value_parser = ["cpu", "vulkan"])]
    backend: Option<String>,
    /// Vulkan device (position in `s3tir-train devices`) [default: the best discrete or
    /// integrated GPU, else the CPU driver].
    #[arg(long)]
    device_index: Option<usize>,
    /// Vulkan: do not use float atomics even where the device has them (the compare-and-swap
    /// fallback that drivers without them, e.g. Raspberry Pi 5's, take).
    #[arg(long)]
    no_float_atomics: bool,
    /// Hard primitive budget.
    #[arg(long, default_value_t = 100_000)]
    budget: usize,
    /// Random seed (initial subsampling, bands, view order, splits).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Gabor bands per primitive (modes with bands).
    #[arg(long, default_value_t = 4)]
    bands: usize,
    /// No multi-view consistency loss.
    #[arg(long)]
    no_consist: bool,
    /// No L1 sparsity on Ψ_high.
    #[arg(long)]
    no_sparse: bool,
    /// No TV smoothness on Ψ_β.
    #[arg(long)]
    no_smooth: bool,
    /// Continue the run in --out from its checkpoint (its config.json; only --iters,
    /// --time-budget and --backend may change).
    #[arg(long)]
    resume: bool,
    /// Hold out every k-th view (by name) for evaluation; 0: none.
    #[arg(long, default_value_t = 8)]
    holdout: usize,
    /// Integer downscale of every image at load.
    #[arg(long, default_value_t = 1)]
    downscale: usize,
    /// What 16-bit words are: `ck` (TLinear centikelvin, radiometric) or `counts`.
    #[arg(long, default_value = "ck", value_parser = ["ck", "counts"])]
    units: String,
    /// Read 8-bit colour images as ironbow pseudo-colour thermal instead of RGB.
    #[arg(long)]
    pseudo_colour: bool,
    /// Held-out evaluation interval, training seconds.
    #[arg(long, default_value_t = 30.0)]
    eval_every_s: f64,
    /// Checkpoint interval, training seconds.
    #[arg(long, default_value_t = 60.0)]
    checkpoint_every_s: f64,
    /// β learning rate (β units).
    #[arg(long, default_value_t = 1e-3)]
    beta_lr: f64,
    /// Compute the multi-view consistency loss every k-th iteration.
    #[arg(long, default_value_t = 1)]
    consist_every: u64,
    /// The consistency term's partner view: `previous` pairs consecutive steps (a random view,
    /// then a view overlapping it, warped into the G-buffers kept from the first: no extra
    /// render, the term on every second step); `render` renders the view's best-overlap
    /// partner in the same step (both views get gradients; about 2x the step time).
    #[arg(long, default_value_t = ConsistPartner::Previous)]
    consist_partner: ConsistPartner,
    /// Train for this much training time instead of a number of iterations: `90s`, `10m`,
    /// `1h30m` or plain seconds. Training time is step time, as the error-vs-time plot counts
    /// it (held-out evaluations and checkpoints are not counted). The schedule (warm-up,
    /// densification window, learning-rate decay) keeps its shape and follows the fraction
    /// of the budget spent; --iters then only sets the nominal length it is written in.
    #[arg(long, value_parser = parse_duration)]
    time_budget: Option<f64>,
    /// Density control: densify primitives whose mean view-space positional gradient (3DGS's
    /// statistic, in normalised device coordinates) exceeds this.
    #[arg(long, default_value_t = Densify::default().grad_threshold)]
    densify_grad: f64,
    /// Density control runs from this (schedule) iteration…
    #[arg(long, default_value_t = Densify::default().from)]
    densify_from: u64,
    /// …until this one (and never in the second half of the run)…
    #[arg(long, default_value_t = Densify::default().until)]
    densify_until: u64,
    /// …every this many iterations (0: no density control).
    #[arg(long, default_value_t = Densify::default().every)]
    densify_every: u64,
    /// Density control removes primitives whose opacity is below this.
    #[arg(long, default_value_t = Densify::default().prune_opacity)]
    prune_opacity: f64,
    /// Per-view radiometric response learned with the scene, applied to each training view's
    /// render: `affine` (gain and offset: 8-bit images tone-mapped per frame by automatic gain
    /// control), `offset` (16-bit radiometric frames drifting between flat-field corrections),
    /// `none`, or `auto`: affine for 8-bit input, offset for 16-bit, dropped by mid-run when
    /// the views' learned responses agree (offsets within 0.1 K or half a grey level, gains
    /// within 0.5 %). The responses are anchored to the cameras' mean (mean offset and
    /// log-gain zero), or, when DATA/ffc.txt lists the views taken right after a flat-field
    /// correction, their offsets are pinned at zero there. Held-out views are evaluated raw
    /// and aligned (eval.json, metrics.csv, error_vs_time.png).
    #[arg(long, default_value_t = ResponseKind::Auto)]
    response: ResponseKind,
    /// Weight of the L2 prior on each view's response (offset² + log-gain²).
    #[arg(long, default_value_t = ResponseConfig::default().prior)]
    response_prior: f64,
    /// Adam learning rate of the responses' offsets (normalised units) at the start of the
    /// run; the log-gains' is twice it. Both decay to a tenth over the run.
    #[arg(long, default_value_t = ResponseConfig::default().lr_offset)]
    response_lr: f64,
    /// At the end, time the CPU reference renderer's step on a training view with and without
    /// its shortcuts (capacity.json: cpu_step_ms_*; six CPU passes, so off by default).
    #[arg(long)]
    cpu_timing: bool,
    /// Joint RGB + thermal (TGA-GS): which of the dataset's image sets to train on. A COLMAP
    /// model holding a rig's thermal and RGB images (each with its own camera: thermal pose =
    /// RGB pose composed with the calibrated extrinsic) trains one set of primitives with a
    /// thermal head and an SH colour head: `both` (joint), `thermal` or `rgb` alone.
    #[arg(long, default_value_t = Modality::Both)]
    views: Modality,
    /// Joint: RGB pre-training, the first N iterations on RGB views only, then every view
    /// (paper §3.3; counted inside --iters) [default: 0; `ablation`: a tenth of --iters].
    #[arg(long)]
    rgb_pretrain: Option<u64>,
    /// Joint: each step trains one drawn view only, instead of the view together with the
    /// other camera's image of the same instant (after the RGB pre-training).
    #[arg(long)]
    no_pair_steps: bool,
    /// Joint: RGB views' loss — `l1-low` (TGA-GS's L1-low on a log curve for dark images, plus
    /// D-SSIM), `l1` (L1 + D-SSIM), or `auto`: l1-low when the RGB training views average
    /// below 0.2 (low light).
    #[arg(long, default_value_t = RgbLoss::Auto)]
    rgb_loss: RgbLoss,
    /// Joint: weight of every term of a thermal view's loss.
    #[arg(long, default_value_t = Joint::default().thermal_weight)]
    thermal_weight: f64,
    /// Joint: weight of every term of an RGB view's loss.
    #[arg(long, default_value_t = Joint::default().rgb_weight)]
    rgb_weight: f64,
    /// Weight of the thermal gradient alignment loss (TGA-GS §3.4: rendered normals from the
    /// depth G-buffer against the thermal image's gradients) on thermal views; 0 turns it off
    /// [default: 0.05 in a joint run, 0 in a thermal-only run].
    #[arg(long)]
    thermal_align: Option<f64>,
    /// Joint: also render the held-out thermal views at K× their resolution into
    /// RUN_DIR/renders_sr/ (super-resolved thermal: the shared geometry carries the RGB views'
    /// edges into the thermal head), and that render fused with each view's recorded image
    /// (back-projection: its K×K averages match the recorded pixels) into
    /// RUN_DIR/renders_sr_fused/ [default: the RGB over the thermal resolution in a joint run;
    /// 1: none].
    #[arg(long)]
    sr_scale: Option<usize>,
    /// Degree of the SH colour of runs with RGB views (0–3).
    #[arg(long, default_value_t = 0)]
    sh_degree: usize,
}

/// A duration for `--time-budget`: plain seconds, or numbers with units `h`, `m`, `s`
/// (`1h30m`, `10m`, `90s`, `2.5m`); must be positive.
fn parse_duration(text: &str) -> std::result::Result<f64, String> {
    let t = text.trim();
    let bad = || format!("{text:?} is not a duration (e.g. 600, 90s, 10m, 1h30m)");
    if let Ok(s) = t.parse::<f64>() {
        return if s.is_finite() && s > 0.0 {
            Ok(s)
        } else {
            Err(format!("{text:?}: the duration must be positive"))
        };
    }
    let mut total = 0.0;
    let mut number = String::new();
    for c in t.chars() {
        if c.is_ascii_digit() || c == '.' {
            number.push(c);
            continue;
        }
        let unit = match c {
            'h' => 3600.0,
            'm' => 60.0,
            's' => 1.0,
            _ => return Err(bad()),
        };
        let n: f64 = number.parse().map_err(|_| bad())?;
        total += n * unit;
        number.clear();
    }
    if !(number.is_empty() && total.is_finite() && total > 0.0) {
        return Err(bad());
    }
    Ok(total)
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match (cli.command, cli.train) {
        (Some(Command::Devices { json }), _) => devices(json),
        (Some(Command::Train(a)), _) => train_cmd(*a),
        (None, Some(a)) => train_cmd(a),
        (Some(Command::Bench(a)), _) if a.mesh => mesh_bench_cmd(&a),
        (Some(Command::Bench(a)), _) => bench_cmd(a),
        (
            Some(Command::Eval {
                run_dir,
                json,
                backend,
                device_index,
                truth,
            }),
            _,
        ) => {
            if truth {
                truth_cmd(&run_dir, json)
            } else {
                eval_cmd(&run_dir, json, &backend, device_index)
            }
        }
        (Some(Command::Ablation(a)), _) => ablation_cmd(*a),
        (Some(Command::Mesh(a)), _) => mesh_cmd(&a),
        (Some(Command::Compare { runs, out }), _) => compare_cmd(&runs, &out),
        (
            Some(Command::Synth {
                out,
                views,
                width,
                height,
            }),
            _,
        ) => {
            let cfg = s3tir_trainer::dataset::synth::SynthConfig {
                views,
                width,
                height,
                f_px: 40.0 * width as f64 / 48.0,
                ..Default::default()
            };
            s3tir_trainer::dataset::synth::write_scene(&out, &cfg)
                .with_context(|| format!("writing the synthetic scene to {}", out.display()))?;
            println!("synthetic scene written to {}", out.display());
            Ok(())
        }
        (None, None) => {
            bail!("nothing to do: give DATA --out RUN_DIR, or a subcommand (see --help)")
        }
    }
}

fn train_cmd(a: TrainArgs) -> Result<()> {
    let (Some(data), Some(out)) = (a.data.clone(), a.out.clone()) else {
        bail!("training needs DATA and --out RUN_DIR");
    };
    let data = if !a.resume
        && data
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    {
        pose_session(&a, &data, &out)?
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
        if let Some(b) = &a.backend
            && *b != cfg.backend
        {
            println!(
                "--resume: switching from the run's {} backend to {b} (--backend)",
                cfg.backend
            );
            cfg.backend = b.clone();
        }
        cfg
    } else {
        new_config(&a, data)?
    };
    let dataset = Dataset::load(&cfg.data, &cfg.load)
        .with_context(|| format!("loading dataset {}", cfg.data.display()))?;
    println!(
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
    println!("training on the {} backend", cfg.backend);
    match cfg.backend.as_str() {
        "vulkan" => train_vulkan(
            cfg,
            dataset,
            &out,
            a.resume,
            a.device_index,
            a.no_float_atomics,
        ),
        _ => run_training(cfg, dataset, CpuBackend::default(), &out, a.resume),
    }
}

/// The configuration of a new run from the command line (`data`: the dataset folder).
fn new_config(a: &TrainArgs, data: PathBuf) -> Result<TrainConfig> {
    let mut cfg = TrainConfig::new(data);
    cfg.load = LoadOptions {
        holdout_every: a.holdout,
        thermal_units: if a.units == "counts" {
            ThermalUnits::RawCounts
        } else {
            ThermalUnits::CentiKelvin
        },
        colour: if a.pseudo_colour {
            ColourMode::Pseudo
        } else {
            ColourMode::Rgb
        },
        downscale: a.downscale,
        images_dir: None,
        modality: a.views,
    };
    if a.sh_degree > s3tir_trainer::sh::SH_MAX_DEGREE {
        bail!(
            "--sh-degree {} is above the highest supported degree, {}",
            a.sh_degree,
            s3tir_trainer::sh::SH_MAX_DEGREE
        );
    }
    if let Some(w) = a.thermal_align
        && !(w >= 0.0 && w.is_finite())
    {
        bail!("--thermal-align must be a finite weight ≥ 0, got {w}");
    }
    for (flag, w) in [
        ("--thermal-weight", a.thermal_weight),
        ("--rgb-weight", a.rgb_weight),
    ] {
        if !(w >= 0.0 && w.is_finite()) {
            bail!("{flag} must be a finite weight ≥ 0, got {w}");
        }
    }
    cfg.sh_degree = a.sh_degree;
    cfg.joint = Joint {
        rgb_pretrain: a.rgb_pretrain.unwrap_or(0),
        thermal_weight: a.thermal_weight,
        rgb_weight: a.rgb_weight,
        rgb_loss: a.rgb_loss,
        thermal_align: a.thermal_align,
        sr_scale: a.sr_scale,
        pair_steps: !a.no_pair_steps,
        ..Joint::default()
    };
    cfg.mode = a.mode;
    cfg.iters = a.iters.unwrap_or(30_000);
    cfg.time_budget_s = a.time_budget;
    cfg.densify.grad_threshold = a.densify_grad;
    cfg.densify.from = a.densify_from;
    cfg.densify.until = a.densify_until;
    cfg.densify.every = a.densify_every;
    cfg.densify.prune_opacity = a.prune_opacity;
    cfg.response.kind = a.response;
    cfg.response.prior = a.response_prior;
    cfg.response.lr_offset = a.response_lr;
    cfg.response.lr_log_gain = 2.0 * a.response_lr;
    cfg.cpu_timing = a.cpu_timing;
    cfg.warmup = a.warmup;
    cfg.budget = a.budget;
    cfg.seed = a.seed;
    cfg.bands = a.bands;
    cfg.consist = !a.no_consist;
    cfg.sparse = !a.no_sparse;
    cfg.smooth = !a.no_smooth;
    cfg.eval_every_s = a.eval_every_s;
    cfg.checkpoint_every_s = a.checkpoint_every_s;
    cfg.lr.beta = a.beta_lr;
    cfg.consist_every = a.consist_every;
    cfg.consist_partner = a.consist_partner;
    cfg.backend = a.backend.clone().unwrap_or_else(|| "cpu".into());
    Ok(cfg)
}

/// `s3tir-train SESSION.mcap`: the poses stage (calib's, in-process) writes the dataset first.
fn pose_session(a: &TrainArgs, session: &Path, out: &Path) -> Result<PathBuf> {
    use s3tir_calib::calfile::CalibrationFile;
    use s3tir_calib::poses::{self, PosesOptions};
    if out.exists() {
        bail!(
            "{} exists: s3tir-train never overwrites a run (choose another --out)",
            out.display()
        );
    }
    let dataset = a.dataset.clone().unwrap_or_else(|| {
        let mut name = out.file_name().unwrap_or_default().to_os_string();
        name.push("-dataset");
        out.with_file_name(name)
    });
    let cal = match &a.calibration {
        Some(p) => Some(CalibrationFile::read(p)?),
        None => None,
    };
    let opts = PosesOptions {
        colmap: a.colmap.clone(),
        tags: a.tags.clone(),
        with_rgb: a.with_rgb,
        holdout_every: a.holdout,
        progress: true,
        ..PosesOptions::default()
    };
    println!(
        "posing session {} into {}",
        session.display(),
        dataset.display()
    );
    let report = poses::session_to_dataset(session, cal.as_ref(), &dataset, &opts)
        .with_context(|| format!("poses from {}", session.display()))?;
    print!("{}", poses::summary(&report));
    Ok(dataset)
}

#[cfg(feature = "vulkan")]
fn vulkan_options(
    device_index: Option<usize>,
    no_float_atomics: bool,
) -> s3tir_trainer::gpu::ContextOptions {
    use s3tir_trainer::gpu::{ContextOptions, DeviceChoice};
    ContextOptions {
        device: device_index.map_or(DeviceChoice::Best, DeviceChoice::Index),
        disable_float_atomics: no_float_atomics,
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
) -> Result<()> {
    let backend = s3tir_trainer::gpu::backend::VulkanBackend::new(
        &vulkan_options(device_index, no_float_atomics),
        s3tir_trainer::render::RenderSettings::default(),
    )
    .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
    run_training(cfg, dataset, backend, out, resume)
}

#[cfg(not(feature = "vulkan"))]
fn train_vulkan(
    _: TrainConfig,
    _: Dataset,
    _: &Path,
    _: bool,
    _: Option<usize>,
    _: bool,
) -> Result<()> {
    bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
}

#[cfg(feature = "vulkan")]
fn bench_cmd(a: BenchArgs) -> Result<()> {
    use s3tir_trainer::gpu::bench::{self, BenchOptions};
    let (width, height, views, primitives, steps) = if a.real_size {
        (320, 256, 24, 30_000, 10)
    } else {
        (
            a.width.unwrap_or(96),
            a.height.unwrap_or(72),
            a.views.unwrap_or(12),
            a.primitives.unwrap_or(2000),
            a.steps,
        )
    };
    let opts = BenchOptions {
        width,
        height,
        views,
        primitives,
        steps,
        warmup_steps: a.warmup_steps,
        device: vulkan_options(a.device_index, a.no_float_atomics),
    };
    let r = bench::run(&opts, &mut |line| eprintln!("bench: {line}"))?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    println!(
        "device {}; scene {}x{}, {} primitives, {} timed steps per configuration",
        r.device, r.width, r.height, r.primitives, r.steps
    );
    println!(
        "  CPU backend, s3tir mode     {:8.2} steps/s on {} threads, {:.2} on one ({:.2}x)",
        r.cpu_steps_per_s, r.cpu_threads, r.cpu_one_thread_steps_per_s, r.cpu_parallel_speedup
    );
    println!(
        "  Vulkan backend, s3tir mode  {:8.2} steps/s",
        r.s3tir_steps_per_s
    );
    println!(
        "  Vulkan backend, 3dgs mode   {:8.2} steps/s",
        r.gaussian_steps_per_s
    );
    println!(
        "  Vulkan / CPU                {:8.2}x  (goal >= 3)",
        r.vulkan_speedup_over_cpu
    );
    println!(
        "  s3tir cost / 3dgs           {:8.2}x  (goal <= 1.5)",
        r.s3tir_cost_over_gaussian
    );
    println!(
        "  s3tir, partner rendered     {:8.2} steps/s, {:.2}x 3dgs  (--consist-partner render)",
        r.s3tir_render_partner_steps_per_s, r.s3tir_render_partner_cost_over_gaussian
    );
    println!(
        "  process CPU time per step: CPU backend {:.1} ms, Vulkan s3tir {:.1} ms, Vulkan 3dgs {:.1} ms",
        r.cpu_backend_cpu_ms_per_step, r.vulkan_cpu_ms_per_step, r.gaussian_cpu_ms_per_step
    );
    println!(
        "  peak GPU memory             {:8.1} MiB",
        r.peak_gpu_bytes as f64 / (1024.0 * 1024.0)
    );
    println!(
        "  host reads per step         {:8.1} ({:.0} bytes; {:.1} submissions), Vulkan s3tir",
        r.host_reads_per_step, r.host_read_bytes_per_step, r.submissions_per_step
    );
    println!("  {}", r.joint_line());
    println!("  GPU time (dispatches) per step:  s3tir mode              3dgs mode");
    for k in &r.kernels {
        println!(
            "    {:<26} {:8.3} ms ({:4.1}) {:5.1} %  {:8.3} ms ({:4.1})",
            k.kernel,
            k.ms_per_step,
            k.dispatches_per_step,
            100.0 * k.share,
            k.gaussian_ms_per_step,
            k.gaussian_dispatches_per_step
        );
    }
    let total = |f: fn(&bench::KernelShare) -> f64| r.kernels.iter().map(f).sum::<f64>();
    println!(
        "    {:<26} {:8.3} ms ({:4.1})          {:8.3} ms ({:4.1})",
        "all kernels",
        total(|k| k.ms_per_step),
        total(|k| k.dispatches_per_step),
        total(|k| k.gaussian_ms_per_step),
        total(|k| k.gaussian_dispatches_per_step)
    );
    Ok(())
}

#[cfg(not(feature = "vulkan"))]
fn bench_cmd(_: BenchArgs) -> Result<()> {
    bail!(
        "this s3tir-train was built without the `vulkan` feature: there is nothing to compare the CPU with"
    )
}

/// Options of `s3tir-train mesh`.
#[derive(Debug, Args)]
struct MeshArgs {
    /// Run folder written by training (any backend's).
    run_dir: PathBuf,
    /// Output mesh (binary PLY); the colour-mapped copy goes beside it as OUT_thermal.ply.
    #[arg(long, default_value = "mesh.ply")]
    out: PathBuf,
    /// Voxel edge in metres [default: the scene's extent / --resolution, grown until the
    /// volume fits --memory-budget-mib].
    #[arg(long = "voxel-size-m")]
    voxel_size_m: Option<f64>,
    /// Voxels along the scene's longest side when the voxel is automatic.
    #[arg(long, default_value_t = 512)]
    resolution: usize,
    /// Truncation distance of the signed-distance volume, in voxels.
    #[arg(long, default_value_t = 3.0)]
    trunc_voxels: f64,
    /// Memory the volume may use, MiB (the renders kept for fusion come on top: ~3.6 MB per
    /// 640×512 view with colour).
    #[arg(long, default_value_t = 1024)]
    memory_budget_mib: u64,
    /// Rendered alpha from which a pixel is surface.
    #[arg(long, default_value_t = 0.5)]
    min_alpha: f32,
    /// Observation weight a voxel needs to take part in the surface, in head-on-equivalent
    /// views: each view counts |cos θ| of the angle between its ray and the surface (a grazing
    /// view measures distance badly), so 1 is one head-on view or two at 60°.
    #[arg(long, default_value_t = 1.0)]
    min_weight: f32,
    /// Score the mesh against the dataset's truth surface (DATA/truth/surface.ply, written by
    /// `s3tir-firmware-sim scene`): Chamfer distance, F-score at --tau-m, kelvin MAE.
    #[arg(long)]
    truth: bool,
    /// Distance threshold of the F-score and of the vertices whose kelvin is scored, metres.
    #[arg(long, default_value_t = 0.02)]
    tau_m: f64,
    /// Backend that renders the views.
    #[arg(long, value_parser = ["cpu", "vulkan"], default_value = "cpu")]
    backend: String,
    /// Vulkan device index (see `devices`; default: the best device).
    #[arg(long)]
    device_index: Option<usize>,
    /// Print one JSON object (files, voxel, blocks, vertices, triangles, seconds per stage,
    /// peak memory, the truth score).
    #[arg(long)]
    json: bool,
}

/// Options of `s3tir-train bench`.
#[derive(Debug, Args)]
struct BenchArgs {
    /// Print one JSON object (`cpu_steps_per_s`, `vulkan_steps_per_s`, `s3tir_steps_per_s`,
    /// `gaussian_steps_per_s`, `device`, ratios, `kernels`).
    #[arg(long)]
    json: bool,
    /// Image width of the benchmark scene [default: 96; --mesh: 640].
    #[arg(long)]
    width: Option<usize>,
    /// Image height of the benchmark scene [default: 72; --mesh: 512].
    #[arg(long)]
    height: Option<usize>,
    /// Views of the benchmark scene [default: 12; --mesh: 100].
    #[arg(long)]
    views: Option<usize>,
    /// Primitives (constant: densification off) [default: 2000; --mesh: 30000].
    #[arg(long)]
    primitives: Option<usize>,
    /// Timed training steps per configuration. They run in rounds of at most 5 steps, the
    /// configurations taking turns, so a slow spell of the machine falls on all of them alike.
    #[arg(long, default_value_t = 20)]
    steps: usize,
    /// Untimed steps first (pipeline compilation, buffer growth).
    #[arg(long, default_value_t = 3)]
    warmup_steps: usize,
    /// Vulkan device (position in `s3tir-train devices`).
    #[arg(long)]
    device_index: Option<usize>,
    /// Force the compare-and-swap fallback instead of float atomics.
    #[arg(long)]
    no_float_atomics: bool,
    /// The realistic configuration instead of the small default scene: 320×256, 24 views,
    /// 30 000 primitives, 10 timed steps (a real thermal scene trained at half resolution;
    /// overrides --width, --height, --views, --primitives and --steps).
    #[arg(long)]
    real_size: bool,
    /// Benchmark `mesh` instead of training: seconds per stage (render, fuse, extract) and
    /// peak memory of meshing 100 views of 640×512 with 30 000 primitives on the CPU backend
    /// (--width, --height, --views, --primitives change it).
    #[arg(long)]
    mesh: bool,
}

/// The training loop on any backend, with a progress bar and Ctrl-C handling.
fn run_training<B: Backend>(
    cfg: TrainConfig,
    dataset: Dataset,
    backend: B,
    out: &Path,
    resume: bool,
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
            println!(
                "interrupted at iteration {iteration}: checkpoint written to {}; continue with --resume",
                out.join(files::CHECKPOINT).display()
            );
            std::process::exit(130);
        }
        Outcome::Finished => {
            let cap = trainer.capacity_report();
            println!(
                "done: {} primitives in {}",
                trainer.prims.len(),
                out.display()
            );
            for f in [
                files::PLY,
                files::METRICS_CSV,
                files::METRICS_PNG,
                files::EVAL,
                files::CAPACITY,
                files::BETA_HIST,
                files::RENDERS,
                files::RENDERS_SR,
                files::GBUFFERS,
            ] {
                if out.join(f).exists() {
                    println!("  {}", out.join(f).display());
                }
            }
            println!(
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
                println!("view response: {}", r.describe());
            }
            if let Some(why) = &cap.rgb_loss {
                println!(
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
            println!(
                "density control: {} rounds, {} cloned, {} split, {} pruned; {} primitives at the end (budget {})",
                cap.densify_rounds.len(),
                cap.densify_cloned,
                cap.densify_split,
                cap.densify_pruned,
                cap.primitives,
                trainer.cfg.budget
            );
            if let Some(b) = budget {
                println!(
                    "time budget: {:.1} s of training time of {b:.1} s ({} iterations); {:.1} s wall clock with evaluations, checkpoints and outputs",
                    trainer.train_seconds,
                    trainer.iteration,
                    wall.elapsed().as_secs_f64()
                );
            }
            Ok(())
        }
    }
}

/// The held-out evaluation of `run_dir` on `backend` (`cpu` or `vulkan`).
fn evaluate_on(
    run_dir: &Path,
    backend: &str,
    device_index: Option<usize>,
) -> Result<train::RunEval> {
    let what = || format!("evaluating {} on the {backend} backend", run_dir.display());
    match backend {
        #[cfg(feature = "vulkan")]
        "vulkan" => {
            let b = s3tir_trainer::gpu::backend::VulkanBackend::new(
                &vulkan_options(device_index, false),
                s3tir_trainer::render::RenderSettings::default(),
            )
            .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
            train::evaluate_run(run_dir, b).with_context(what)
        }
        #[cfg(not(feature = "vulkan"))]
        "vulkan" => {
            let _ = device_index;
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        _ => train::evaluate_run(run_dir, CpuBackend::default()).with_context(what),
    }
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

/// `s3tir-train ablation`: the four runs and their table.
fn ablation_cmd(mut a: TrainArgs) -> Result<()> {
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
    match base.backend.as_str() {
        #[cfg(feature = "vulkan")]
        "vulkan" => {
            let opts = vulkan_options(a.device_index, a.no_float_atomics);
            ablation_on(&base, &out, &mut || {
                s3tir_trainer::gpu::backend::VulkanBackend::new(
                    &opts,
                    s3tir_trainer::render::RenderSettings::default(),
                )
                .map_err(|e| train::TrainError::Config {
                    reason: format!("opening the Vulkan backend: {e}"),
                })
            })
        }
        #[cfg(not(feature = "vulkan"))]
        "vulkan" => {
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        _ => ablation_on(&base, &out, &mut || Ok(CpuBackend::default())),
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

fn eval_cmd(run_dir: &Path, json: bool, backend: &str, device_index: Option<usize>) -> Result<()> {
    let run = evaluate_on(run_dir, backend, device_index)?;
    let e = &run.eval;
    if json {
        let mut v = serde_json::to_value(&run)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("view_count".into(), e.views.len().into());
            o.insert("backend".into(), backend.into());
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let k = |x: Option<f64>| x.map_or_else(|| "—".to_owned(), |v| format!("{v:.3} K"));
    let db = |x: Option<f64>| x.map_or_else(|| "—".to_owned(), |v| format!("{v:6.2} dB"));
    println!(
        "raw: the render as it is; aligned: under the view's fitted affine map (PSNR) or median offset (MAE)"
    );
    for v in &e.views {
        println!(
            "{:<24} PSNR {:6.2} dB (aligned {})  SSIM {:.4}  MAE {} (aligned {})  RMSE {}",
            v.name,
            v.psnr,
            db(v.psnr_aligned),
            v.ssim,
            k(v.kelvin_mae),
            k(v.kelvin_mae_aligned),
            k(v.kelvin_rmse)
        );
    }
    println!(
        "{:<24} PSNR {:6.2} dB (aligned {})  SSIM {:.4}  MAE {} (aligned {})  RMSE {}  ({} views, {} primitives, mode {})",
        "mean",
        e.psnr,
        db(e.psnr_aligned),
        e.ssim,
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

/// `bench --mesh`: the mesh benchmark (see `s3tir_trainer::mesh::bench`).
fn mesh_bench_cmd(a: &BenchArgs) -> Result<()> {
    use s3tir_trainer::mesh::bench::{MeshBenchOptions, run};
    let d = MeshBenchOptions::default();
    let opts = MeshBenchOptions {
        width: a.width.unwrap_or(d.width),
        height: a.height.unwrap_or(d.height),
        views: a.views.unwrap_or(d.views),
        primitives: a.primitives.unwrap_or(d.primitives),
        ..d
    };
    let r = run(&opts, &mut |_, _, _| {}, &mut |line| {
        eprintln!("bench: {line}")
    })?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    let mib = |b: Option<u64>| {
        b.map_or_else(
            || "unknown".to_owned(),
            |b| format!("{:.0} MiB", b as f64 / f64::from(1 << 20)),
        )
    };
    let st = &r.stats;
    println!(
        "mesh: {} views of {}x{}, {} primitives, CPU backend on {} threads",
        st.views_rendered, r.width, r.height, r.primitives, r.threads
    );
    println!(
        "  render {:.1} s, fuse {:.1} s ({:.2}x the render), extract {:.1} s ({:.2}x); total {:.1} s",
        st.render_s, st.fuse_s, r.fuse_over_render, st.extract_s, r.extract_over_render, r.seconds
    );
    println!(
        "  voxel {:.2} mm, {} blocks: volume {:.0} MiB, renders kept {:.0} MiB; peak memory {} (before meshing {})",
        st.voxel_m * 1e3,
        st.blocks,
        st.volume_bytes as f64 / f64::from(1 << 20),
        st.renders_bytes as f64 / f64::from(1 << 20),
        mib(r.peak_rss_bytes),
        mib(r.rss_before_bytes)
    );
    println!("  {} vertices, {} triangles", st.vertices, st.triangles);
    Ok(())
}

/// `mesh`: progress bars per stage, the summary as text or JSON.
fn mesh_cmd(a: &MeshArgs) -> Result<()> {
    use s3tir_trainer::mesh::run::{MeshOptions, MeshStage, mesh_run};
    let opts = MeshOptions {
        voxel_m: a.voxel_size_m,
        resolution: a.resolution,
        trunc_voxels: a.trunc_voxels,
        memory_budget_bytes: a.memory_budget_mib.saturating_mul(1 << 20),
        min_alpha: a.min_alpha,
        min_weight: a.min_weight,
        tau_m: a.tau_m,
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>8} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut progress = |stage: MeshStage, done: usize, total: usize| {
        bar.set_message(match stage {
            MeshStage::Render => "render",
            MeshStage::Fuse => "fuse",
            MeshStage::Extract => "extract",
        });
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let what = || format!("meshing {} into {}", a.run_dir.display(), a.out.display());
    let s = match a.backend.as_str() {
        #[cfg(feature = "vulkan")]
        "vulkan" => {
            let b = s3tir_trainer::gpu::backend::VulkanBackend::new(
                &vulkan_options(a.device_index, false),
                s3tir_trainer::render::RenderSettings::default(),
            )
            .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
            mesh_run(&a.run_dir, &a.out, &opts, a.truth, b, &mut progress).with_context(what)?
        }
        #[cfg(not(feature = "vulkan"))]
        "vulkan" => {
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        _ => mesh_run(
            &a.run_dir,
            &a.out,
            &opts,
            a.truth,
            CpuBackend::default(),
            &mut progress,
        )
        .with_context(what)?,
    };
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    let st = &s.stats;
    println!(
        "{} vertices, {} triangles from {} of {} views; voxel {:.2} mm, truncation {:.2} mm, {} blocks ({:.1} MiB)",
        st.vertices,
        st.triangles,
        st.views,
        st.views_rendered,
        st.voxel_m * 1e3,
        st.trunc_m * 1e3,
        st.blocks,
        st.volume_bytes as f64 / f64::from(1 << 20)
    );
    println!(
        "render {:.1} s, fuse {:.1} s, extract {:.1} s; peak memory {}",
        st.render_s,
        st.fuse_s,
        st.extract_s,
        s.peak_rss_bytes.map_or_else(
            || "unknown".to_owned(),
            |b| format!("{:.0} MiB", b as f64 / f64::from(1 << 20))
        )
    );
    if let Some(t) = &s.truth {
        println!(
            "against truth: Chamfer {:.2} mm (accuracy {:.2}, completeness {:.2}), F-score {:.3} at {:.0} mm (precision {:.3}, recall {:.3}), vertex temperature MAE {:.3} K",
            t.chamfer_m * 1e3,
            t.accuracy_m * 1e3,
            t.completeness_m * 1e3,
            t.f_score,
            t.tau_m * 1e3,
            t.precision,
            t.recall,
            t.kelvin_mae
        );
    }
    println!(
        "wrote {} (kelvin{}) and {} (ironbow {:.2}–{:.2} K)",
        s.out.display(),
        if s.colour { " and RGB" } else { "" },
        s.thermal_out.display(),
        s.kelvin_lo,
        s.kelvin_hi
    );
    Ok(())
}

fn compare_cmd(runs: &[PathBuf], out: &Path) -> Result<()> {
    let mut series = Vec::new();
    for r in runs {
        let rows = report::read_rows(&r.join(files::METRICS_CSV))
            .with_context(|| format!("reading the metrics of {}", r.display()))?;
        let mode = train::load_config(r).map_or_else(|_| "?".to_owned(), |c| c.mode.to_string());
        let name = r.file_name().map_or_else(
            || r.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        if let Some(last) = rows.last() {
            println!(
                "{name:<20} {mode:<6} iter {:>6}  {:8.1} s  PSNR {:6.2} dB (aligned {})  SSIM {:.4}  MAE {}  {} primitives",
                last.iteration,
                last.seconds,
                last.psnr,
                last.psnr_aligned
                    .map_or_else(|| "—".into(), |v| format!("{v:.2} dB")),
                last.ssim,
                last.kelvin_mae
                    .map_or_else(|| "—".into(), |v| format!("{v:.3} K")),
                last.primitives
            );
        }
        series.push((format!("{name} ({mode})"), rows));
    }
    report::plot_runs(out, &series).with_context(|| format!("plotting {}", out.display()))?;
    println!("plot: {}", out.display());
    Ok(())
}

#[cfg(feature = "vulkan")]
fn devices(json: bool) -> Result<()> {
    use s3tir_trainer::gpu::VulkanInstance;

    let instance = VulkanInstance::new()?;
    let reports = instance.reports()?;
    if json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
        return Ok(());
    }
    const MIB: f64 = 1024.0 * 1024.0;
    for r in &reports {
        println!("[{}] {} ({})", r.index, r.name, r.device_type);
        println!("    driver            {} {}", r.driver_name, r.driver_info);
        println!("    Vulkan API        {}", r.api_version);
        for (i, h) in r.memory_heaps.iter().enumerate() {
            let local = if h.device_local {
                "device-local"
            } else {
                "host"
            };
            println!(
                "    memory heap {i}     {:.0} MiB ({local})",
                h.size_bytes as f64 / MIB
            );
        }
        println!(
            "    storage buffer    max range {:.0} MiB",
            r.max_storage_buffer_range_bytes as f64 / MIB
        );
        println!(
            "    compute           {} KiB shared memory, {} invocations per workgroup",
            r.max_compute_shared_memory_bytes / 1024,
            r.max_compute_workgroup_invocations
        );
        println!(
            "    subgroups         size {}, {} ({})",
            r.subgroup_size,
            r.subgroup_operations.join(" "),
            if r.subgroup_in_compute {
                "in compute"
            } else {
                "NOT in compute"
            }
        );
        let yn = |b: bool| if b { "yes" } else { "no" };
        println!(
            "    float atomics     buffer add {}, shared add {}{}",
            yn(r.float_atomics.buffer_f32_add),
            yn(r.float_atomics.shared_f32_add),
            if r.float_atomics.buffer_f32_add {
                ""
            } else {
                " (kernels use the CAS/reduction fallback)"
            }
        );
        println!(
            "    timestamps        {}",
            if r.compute_timestamp_bits > 0 {
                format!(
                    "{} bits, {} ns/tick",
                    r.compute_timestamp_bits, r.timestamp_period_ns
                )
            } else {
                "not on compute queues".to_owned()
            }
        );
    }
    Ok(())
}

#[cfg(not(feature = "vulkan"))]
fn devices(_json: bool) -> Result<()> {
    anyhow::bail!(
        "this s3tir-train was built without the `vulkan` feature: it has no Vulkan backend"
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::parse_duration;

    #[test]
    fn durations_read_as_seconds() {
        assert_eq!(parse_duration("600").unwrap(), 600.0);
        assert_eq!(parse_duration("90s").unwrap(), 90.0);
        assert_eq!(parse_duration("10m").unwrap(), 600.0);
        assert_eq!(parse_duration("2.5m").unwrap(), 150.0);
        assert_eq!(parse_duration("1h30m").unwrap(), 5400.0);
        for bad in ["", "0", "-5", "10x", "m", "5m3", "nan", "0s"] {
            assert!(parse_duration(bad).is_err(), "{bad:?} must be refused");
        }
    }
}
