//! The training options (`s3tir-train DATA …`, `train`, `ablation`) and the run configuration
//! they make.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};
use s3tir_trainer::dataset::images::ColourMode;
use s3tir_trainer::dataset::{LoadOptions, Modality, ThermalUnits};
use s3tir_trainer::train::{
    BackendKind, ConsistPartner, DEFAULT_RGB_PRETRAIN_FRACTION, Joint, Mode, ResponseKind, RgbLoss,
    TrainConfig,
};

/// Training options. Defaults are the paper's (§4.1); see the trainer's `train` module docs.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Dataset folder (COLMAP `sparse/0/` or `sparse/` + `images/`), a session recorded by
    /// s3tir-capture (`.mcap`), or a folder of thermal images (radiometric JPEGs, TIFFs, DJI
    /// shots with GPS and gimbal angles): a session or an image folder is posed first
    /// (`s3tir-calib poses`) into --dataset, then trained on.
    #[arg(required = true)]
    pub data: Option<PathBuf>,
    /// Session or folder input: where to write the posed dataset [default: RUN_DIR-dataset
    /// beside the run].
    #[cfg(feature = "session")]
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Session input: how it is posed (`s3tir-calib poses`' options; --holdout holds out
    /// the posed views too).
    #[cfg(feature = "session")]
    #[command(flatten, next_help_heading = "Session input (posing a recorded .mcap)")]
    pub posing: s3tir_calib::poses::args::PosingArgs,
    /// Folder input: how a folder of thermal images is read and posed (`s3tir-calib poses
    /// DIR`'s options; --calibration and --holdout serve it too).
    #[cfg(feature = "session")]
    #[command(
        flatten,
        next_help_heading = "Folder input (posing a folder of thermal images)"
    )]
    pub folder: s3tir_calib::poses::folder::args::FolderArgs,
    /// Run folder (checkpoint, metrics.csv, plots, PLY, renders and G-buffers of the held-out
    /// views: grey PNGs plus exact f32 `.npy` planes, capacity.json, eval.json).
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// s3tir (learnable β + bands), 3dgs (β ≡ 2, no bands), ges (learnable β, no bands),
    /// gabor (bands, β ≡ 2).
    #[arg(long, default_value_t = TrainConfig::defaults().mode)]
    pub mode: Mode,
    /// Iterations [default: 30000; on --resume: the run's own].
    #[arg(long)]
    pub iters: Option<u64>,
    /// Gaussian warm-up iterations (β ≡ 2, bands off).
    #[arg(long, default_value_t = TrainConfig::defaults().warmup)]
    pub warmup: u64,
    /// Iterations over which the band learning rates rise linearly from 0 to their value after
    /// the warm-up (0: all bands at full rate at once, as the paper; measured no better on the
    /// real facade as long as the warm-up, so off by default).
    #[arg(long, default_value_t = TrainConfig::defaults().band_ramp)]
    pub band_ramp: u64,
    /// Compute backend: `auto` (the best Vulkan device that passes the trainer's checks, else
    /// the CPU; the choice and its reason are printed and stored in config.json), `vulkan` or
    /// `cpu` [default: auto; on --resume: the run's own].
    #[arg(long, value_enum)]
    pub backend: Option<BackendChoice>,
    /// Vulkan device (position in `s3tir-train devices`) [default: the best discrete or
    /// integrated GPU, else the CPU driver].
    #[arg(long)]
    pub device_index: Option<usize>,
    /// Vulkan: do not use float atomics even where the device has them (the compare-and-swap
    /// fallback that drivers without them, e.g. Raspberry Pi 5's, take).
    #[arg(long)]
    pub no_float_atomics: bool,
    /// Hard primitive budget. Under a short --time-budget on a slow device fewer primitives
    /// can train better: on the real thermal facade (8 minutes, lavapipe) 10 000 ended 1 dB
    /// above the default (scripts/real-data/README.md).
    #[arg(long, default_value_t = TrainConfig::defaults().budget)]
    pub budget: usize,
    /// Random seed (initial subsampling, bands, view order, splits).
    #[arg(long, default_value_t = TrainConfig::defaults().seed)]
    pub seed: u64,
    /// Gabor bands per primitive (modes with bands).
    #[arg(long, default_value_t = TrainConfig::defaults().bands)]
    pub bands: usize,
    /// No multi-view consistency loss.
    #[arg(long)]
    pub no_consist: bool,
    /// No L1 sparsity on Ψ_high.
    #[arg(long)]
    pub no_sparse: bool,
    /// No TV smoothness on Ψ_β.
    #[arg(long)]
    pub no_smooth: bool,
    /// Continue the run in --out from its checkpoint (its config.json; only --iters,
    /// --time-budget and --backend may change).
    #[arg(long)]
    pub resume: bool,
    /// Print one JSON object summarising the run on stdout when it ends (outcome, iterations,
    /// seconds, primitives, density control, held-out figures, files); the human-readable
    /// lines go to stderr.
    #[arg(long)]
    pub json: bool,
    /// Hold out every k-th view (by name) for evaluation; 0: none.
    #[arg(long, default_value_t = LoadOptions::default().holdout_every)]
    pub holdout: usize,
    /// Integer downscale of every image at load.
    #[arg(long, default_value_t = LoadOptions::default().downscale)]
    pub downscale: usize,
    /// What 16-bit words are: `ck` (TLinear centikelvin, radiometric) or `counts`.
    #[arg(long, value_enum, default_value_t = Units::of(LoadOptions::default().thermal_units))]
    pub units: Units,
    /// Read 8-bit colour images as ironbow pseudo-colour thermal instead of RGB.
    #[arg(long)]
    pub pseudo_colour: bool,
    /// Held-out evaluation interval, training seconds.
    #[arg(long, default_value_t = TrainConfig::defaults().eval_every_s)]
    pub eval_every_s: f64,
    /// Checkpoint interval, training seconds.
    #[arg(long, default_value_t = TrainConfig::defaults().checkpoint_every_s)]
    pub checkpoint_every_s: f64,
    /// β learning rate (β units).
    #[arg(long, default_value_t = TrainConfig::defaults().lr.beta)]
    pub beta_lr: f64,
    /// Compute the multi-view consistency loss every k-th iteration.
    #[arg(long, default_value_t = TrainConfig::defaults().consist_every)]
    pub consist_every: u64,
    /// Weight λc of the multi-view consistency loss (paper eq. 6: 0.01). 0 keeps the term's
    /// pairing of views (and its cost) without its pull, to separate the two; --no-consist
    /// turns both off.
    #[arg(long, default_value_t = TrainConfig::defaults().weights.consist)]
    pub consist_weight: f64,
    /// The consistency term's partner view: `previous` pairs consecutive steps (a random view,
    /// then a view overlapping it, warped into the G-buffers kept from the first: no extra
    /// render, the term on every second step); `render` renders the view's best-overlap
    /// partner in the same step (both views get gradients; about 2x the step time).
    #[arg(long, default_value_t = TrainConfig::defaults().consist_partner)]
    pub consist_partner: ConsistPartner,
    /// Train for this much training time instead of a number of iterations: `90s`, `10m`,
    /// `1h30m` or plain seconds. Training time is step time, as the error-vs-time plot counts
    /// it (held-out evaluations and checkpoints are not counted). The schedule (warm-up,
    /// densification window, learning-rate decay) keeps its shape and follows the fraction
    /// of the budget spent; --iters then only sets the nominal length it is written in.
    #[arg(long, value_parser = parse_duration)]
    pub time_budget: Option<f64>,
    /// Density control: densify primitives whose mean view-space positional gradient (3DGS's
    /// statistic, in normalised device coordinates) exceeds this.
    #[arg(long, default_value_t = TrainConfig::defaults().densify.grad_threshold)]
    pub densify_grad: f64,
    /// Density control runs from this (schedule) iteration…
    #[arg(long, default_value_t = TrainConfig::defaults().densify.from)]
    pub densify_from: u64,
    /// …until this one (and never in the second half of the run)…
    #[arg(long, default_value_t = TrainConfig::defaults().densify.until)]
    pub densify_until: u64,
    /// …every this many iterations (0: no density control).
    #[arg(long, default_value_t = TrainConfig::defaults().densify.every)]
    pub densify_every: u64,
    /// Density control removes primitives whose opacity is below this.
    #[arg(long, default_value_t = TrainConfig::defaults().densify.prune_opacity)]
    pub prune_opacity: f64,
    /// Density control with the budget full: up to this fraction of the primitives per round,
    /// the weakest by opacity, make room for primitives still over the threshold (0: growth
    /// stops at the budget).
    #[arg(long, default_value_t = TrainConfig::defaults().densify.relocate_frac)]
    pub relocate_frac: f64,
    /// Density control adds at most this fraction of the primitives per round (0: as many as
    /// are over the threshold, up to the budget).
    #[arg(long, default_value_t = TrainConfig::defaults().densify.grow_frac)]
    pub densify_grow_frac: f64,
    /// Bands only where they pay: λ of the band amplitudes' proximal L1 step (an amplitude
    /// whose mean gradient stays below λ goes to exactly zero and is dropped), and the
    /// threshold of the band grant one pass over the training views after the warm-up (a primitive
    /// keeps its bands when one has an RMS gradient above λ). 0: no L1 step, no threshold.
    #[arg(long, default_value_t = TrainConfig::defaults().capacity.band_l1)]
    pub band_l1: f64,
    /// At most this fraction of the primitives keep bands at the grant, highest band gradient
    /// first (1: no budget). The others return to the Gaussian path.
    #[arg(long, default_value_t = TrainConfig::defaults().capacity.band_budget)]
    pub band_budget: f64,
    /// Per-view radiometric response learned with the scene, applied to each training view's
    /// render: `affine` (gain and offset: 8-bit images tone-mapped per frame by automatic gain
    /// control), `offset` (16-bit radiometric frames drifting between flat-field corrections),
    /// `none`, or `auto`: affine for 8-bit input, offset for 16-bit, dropped by mid-run when
    /// the views' learned responses agree (offsets within 0.1 K or half a grey level, gains
    /// within 0.5 %). The responses are anchored to the cameras' mean (mean offset and
    /// log-gain zero), or, when DATA/ffc.txt lists the views taken right after a flat-field
    /// correction, their offsets are pinned at zero there. Held-out views are evaluated raw
    /// and aligned (eval.json, metrics.csv, error_vs_time.png).
    #[arg(long, default_value_t = TrainConfig::defaults().response.kind)]
    pub response: ResponseKind,
    /// Weight of the L2 prior on each view's response (offset² + log-gain²).
    #[arg(long, default_value_t = TrainConfig::defaults().response.prior)]
    pub response_prior: f64,
    /// Adam learning rate of the responses' offsets (normalised units) at the start of the
    /// run; the log-gains' is twice it. Both decay to a tenth over the run.
    #[arg(long, default_value_t = TrainConfig::defaults().response.lr_offset)]
    pub response_lr: f64,
    /// At the end, time the CPU reference renderer's step on a training view with and without
    /// its shortcuts (capacity.json: cpu_step_ms_*; six CPU passes, so off by default).
    #[arg(long)]
    pub cpu_timing: bool,
    /// Joint RGB + thermal (TGA-GS): which of the dataset's image sets to train on. A COLMAP
    /// model holding a rig's thermal and RGB images (each with its own camera: thermal pose =
    /// RGB pose composed with the calibrated extrinsic) trains one set of primitives with a
    /// thermal head and an SH colour head: `both` (joint), `thermal` or `rgb` alone.
    #[arg(long, default_value_t = LoadOptions::default().modality)]
    pub views: Modality,
    /// Joint: RGB pre-training, the first N iterations on RGB views only, then every view
    /// (paper §3.3; counted inside --iters; under --time-budget the same fraction of the
    /// time) [default: a quarter of --iters — measured on the simulated low-light scene, thermal
    /// at 4×: none 25.6 dB, a tenth 25.8 dB, a quarter 25.9–26.0 dB, half level with a quarter
    /// and a larger depth error].
    #[arg(long)]
    pub rgb_pretrain: Option<u64>,
    /// Joint: each step trains one drawn view only, instead of the view together with the
    /// other camera's image of the same instant (after the RGB pre-training).
    #[arg(long)]
    pub no_pair_steps: bool,
    /// Joint: RGB views' loss — `l1-low` (TGA-GS's L1-low on a log curve for dark images, plus
    /// D-SSIM), `l1` (L1 + D-SSIM), or `auto`: l1-low when the RGB training views average
    /// below 0.2 (low light).
    #[arg(long, default_value_t = TrainConfig::defaults().joint.rgb_loss)]
    pub rgb_loss: RgbLoss,
    /// Joint: weight of every term of a thermal view's loss.
    #[arg(long, default_value_t = TrainConfig::defaults().joint.thermal_weight)]
    pub thermal_weight: f64,
    /// Joint: weight of every term of an RGB view's loss.
    #[arg(long, default_value_t = TrainConfig::defaults().joint.rgb_weight)]
    pub rgb_weight: f64,
    /// Weight of the thermal gradient alignment loss (TGA-GS §3.4: rendered normals from the
    /// depth G-buffer against the thermal image's gradients) on thermal views; 0 turns it off
    /// [default: 0.05 in a joint run, 0 in a thermal-only run]. Measured on the simulated
    /// low-light scene (800 iterations): it does nothing measurable at 0.05 (its pull on the
    /// positions 0.03× the other terms'; thermal at 4× 25.78 dB vs 25.77 dB off) and costs
    /// above it (0.5: 25.49 dB, depth error +12 mm; 5: 23.20 dB). The run's summary says how
    /// hard it pulled.
    #[arg(long)]
    pub thermal_align: Option<f64>,
    /// Joint: also render the held-out thermal views at K× their resolution into
    /// RUN_DIR/renders_sr/ (super-resolved thermal: the shared geometry carries the RGB views'
    /// edges into the thermal head), and that render fused with each view's recorded image
    /// (back-projection: its K×K averages match the recorded pixels) into
    /// RUN_DIR/renders_sr_fused/ [default: the RGB over the thermal resolution in a joint run;
    /// 1: none].
    #[arg(long)]
    pub sr_scale: Option<usize>,
    /// Degree of the SH colour of runs with RGB views (0–3). 0 by measurement: on the
    /// simulated low-light scene (800 iterations, two seeds) degree 3 ends 2.1–2.4 dB lower on
    /// held-out RGB and 0.2 dB lower on thermal at 4×: its 15 more coefficients per primitive
    /// cost more than view-dependent colour gives there.
    #[arg(long, default_value_t = TrainConfig::defaults().sh_degree)]
    pub sh_degree: usize,
}

/// `--units`: what a dataset's 16-bit words are — `ck`, TLinear centikelvin (radiometric), or
/// `counts`, raw sensor counts ([`ThermalUnits`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Units {
    Ck,
    Counts,
}

impl Units {
    /// The option naming `units`.
    fn of(units: ThermalUnits) -> Self {
        match units {
            ThermalUnits::CentiKelvin => Units::Ck,
            ThermalUnits::RawCounts => Units::Counts,
        }
    }
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

/// The configuration of a new run from the command line (`data`: the dataset folder).
pub fn new_config(a: &TrainArgs, data: PathBuf) -> Result<TrainConfig> {
    let mut cfg = TrainConfig::new(data);
    cfg.load = LoadOptions {
        holdout_every: a.holdout,
        thermal_units: match a.units {
            Units::Ck => ThermalUnits::CentiKelvin,
            Units::Counts => ThermalUnits::RawCounts,
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
        ("--consist-weight", a.consist_weight),
        ("--band-l1", a.band_l1),
    ] {
        if !(w >= 0.0 && w.is_finite()) {
            bail!("{flag} must be a finite weight ≥ 0, got {w}");
        }
    }
    if !(0.0..=1.0).contains(&a.band_budget) {
        bail!(
            "--band-budget must be a fraction of the primitives in [0, 1], got {}",
            a.band_budget
        );
    }
    cfg.sh_degree = a.sh_degree;
    cfg.joint = Joint {
        rgb_pretrain: a.rgb_pretrain.unwrap_or_else(|| {
            let iters = a.iters.unwrap_or(TrainConfig::defaults().iters);
            (iters as f64 * DEFAULT_RGB_PRETRAIN_FRACTION).round() as u64
        }),
        thermal_weight: a.thermal_weight,
        rgb_weight: a.rgb_weight,
        rgb_loss: a.rgb_loss,
        thermal_align: a.thermal_align,
        sr_scale: a.sr_scale,
        pair_steps: !a.no_pair_steps,
        ..Joint::default()
    };
    cfg.mode = a.mode;
    cfg.iters = a.iters.unwrap_or(TrainConfig::defaults().iters);
    cfg.time_budget_s = a.time_budget;
    cfg.densify.grad_threshold = a.densify_grad;
    cfg.densify.from = a.densify_from;
    cfg.densify.until = a.densify_until;
    cfg.densify.every = a.densify_every;
    cfg.densify.prune_opacity = a.prune_opacity;
    cfg.densify.relocate_frac = a.relocate_frac;
    cfg.densify.grow_frac = a.densify_grow_frac;
    cfg.capacity.band_l1 = a.band_l1;
    cfg.capacity.band_budget = a.band_budget;
    cfg.response.kind = a.response;
    cfg.response.prior = a.response_prior;
    cfg.response.lr_offset = a.response_lr;
    cfg.response.lr_log_gain = 2.0 * a.response_lr;
    cfg.cpu_timing = a.cpu_timing;
    cfg.warmup = a.warmup;
    cfg.band_ramp = a.band_ramp;
    cfg.budget = a.budget;
    cfg.seed = a.seed;
    cfg.bands = a.bands;
    cfg.consist = !a.no_consist;
    cfg.weights.consist = a.consist_weight;
    cfg.sparse = !a.no_sparse;
    cfg.smooth = !a.no_smooth;
    cfg.eval_every_s = a.eval_every_s;
    cfg.checkpoint_every_s = a.checkpoint_every_s;
    cfg.lr.beta = a.beta_lr;
    cfg.consist_every = a.consist_every;
    cfg.consist_partner = a.consist_partner;
    // `auto` is resolved when the backend opens (`train::run`); until then the CPU.
    cfg.backend = a
        .backend
        .and_then(BackendChoice::kind)
        .unwrap_or(BackendKind::Cpu);
    Ok(cfg)
}

/// `--backend`: a backend, or `auto` to take the best that works on this machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum BackendChoice {
    /// The best Vulkan device that passes the trainer's checks, else the CPU.
    #[default]
    Auto,
    Vulkan,
    Cpu,
}

impl BackendChoice {
    /// The backend named (`None`: `auto`, decided when it opens).
    pub fn kind(self) -> Option<BackendKind> {
        match self {
            BackendChoice::Auto => None,
            BackendChoice::Vulkan => Some(BackendKind::Vulkan),
            BackendChoice::Cpu => Some(BackendKind::Cpu),
        }
    }
}

impl std::fmt::Display for BackendChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.kind().map_or("auto", BackendKind::as_str))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use clap::{Args, Command};
    use s3tir_trainer::train::TrainConfig;

    use super::{BackendChoice, TrainArgs, parse_duration};

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

    /// `--iters` and `--backend` state their default in words (they have none in clap: on
    /// `--resume` "not given" keeps the run's own): the words must match the one declared
    /// default, and every default clap shows comes from it.
    #[test]
    fn the_help_states_the_declared_defaults() {
        let cmd = TrainArgs::augment_args(Command::new("s3tir-train"));
        let arg = |id: &str| {
            cmd.get_arguments()
                .find(|a| a.get_id() == id)
                .unwrap_or_else(|| panic!("no --{id} option"))
        };
        let help = |id: &str| {
            arg(id)
                .get_help()
                .map(|h| h.to_string())
                .unwrap_or_default()
        };
        let d = TrainConfig::defaults();
        for (id, default) in [
            ("iters", d.iters.to_string()),
            ("backend", BackendChoice::default().to_string()),
        ] {
            assert!(
                help(id).contains(&format!("[default: {default};")),
                "--{id}'s help must state the declared default {default}: {:?}",
                help(id)
            );
        }
        let shown = |id: &str| {
            arg(id)
                .get_default_values()
                .iter()
                .map(|v| v.to_string_lossy().into_owned())
                .collect::<Vec<_>>()
        };
        assert_eq!(
            shown("warmup"),
            [d.warmup.to_string()],
            "--warmup's default"
        );
        assert_eq!(
            shown("beta_lr"),
            [d.lr.beta.to_string()],
            "--beta-lr's default"
        );
        assert_eq!(shown("mode"), [d.mode.to_string()], "--mode's default");
    }
}
