//! Training configuration: modes (paper Table 2 ablations), schedule, learning rates, density
//! control and capacity adaptation. Serialised into `RUN_DIR/config.json`.

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use super::adam::GroupLrs;
use crate::dataset::LoadOptions;

/// Which primitive family is trained (paper Table 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Mode {
    /// Learnable β and M Gabor bands (the full method).
    #[serde(rename = "s3tir")]
    S3tir,
    /// β ≡ 2, no bands: 3D Gaussian splatting.
    #[serde(rename = "3dgs")]
    Gaussian,
    /// Learnable β, no bands: generalised exponential splatting.
    #[serde(rename = "ges")]
    Ges,
    /// Bands, β ≡ 2: spectral Gabor splatting.
    #[serde(rename = "gabor")]
    Gabor,
}

impl Mode {
    pub fn learns_beta(self) -> bool {
        matches!(self, Mode::S3tir | Mode::Ges)
    }
    pub fn has_bands(self) -> bool {
        matches!(self, Mode::S3tir | Mode::Gabor)
    }
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Mode::S3tir => "s3tir",
            Mode::Gaussian => "3dgs",
            Mode::Ges => "ges",
            Mode::Gabor => "gabor",
        })
    }
}

impl FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "s3tir" => Ok(Mode::S3tir),
            "3dgs" => Ok(Mode::Gaussian),
            "ges" => Ok(Mode::Ges),
            "gabor" => Ok(Mode::Gabor),
            other => Err(format!(
                "unknown mode `{other}` (expected s3tir, 3dgs, ges or gabor)"
            )),
        }
    }
}

/// Loss weights (paper eq. 6 defaults).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Weights {
    pub dssim: f64,
    pub consist: f64,
    pub sparse: f64,
    pub smooth: f64,
}

impl Default for Weights {
    fn default() -> Self {
        Self {
            dssim: 0.2,
            consist: 0.01,
            sparse: 0.005,
            smooth: 0.01,
        }
    }
}

/// How the RGB views' photometric loss is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RgbLoss {
    /// `l1-low` when the RGB training views are dark (mean below [`LOW_LIGHT_MEAN`]), `l1`
    /// otherwise.
    #[default]
    Auto,
    /// TGA-GS's L1-low (paper §3.4) in place of L1, plus D-SSIM: see
    /// [`crate::loss::photometric::l1_low_dssim`].
    L1Low,
    /// 3DGS's `(1 − λ)·L1 + λ·D-SSIM`.
    L1,
}

/// Mean 8-bit RGB value (in [0, 1], sRGB-encoded) below which `--rgb-loss auto` takes the
/// RGB views as low-light. A well-exposed indoor scene averages 0.3–0.5; the simulator's
/// low-light camera (2 % exposure) about 0.1.
pub const LOW_LIGHT_MEAN: f64 = 0.2;

impl fmt::Display for RgbLoss {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RgbLoss::Auto => "auto",
            RgbLoss::L1Low => "l1-low",
            RgbLoss::L1 => "l1",
        })
    }
}

impl FromStr for RgbLoss {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(RgbLoss::Auto),
            "l1-low" => Ok(RgbLoss::L1Low),
            "l1" => Ok(RgbLoss::L1),
            other => Err(format!(
                "unknown RGB loss `{other}` (expected auto, l1-low or l1)"
            )),
        }
    }
}

/// Weight of the thermal gradient alignment loss in runs with RGB views when the user sets
/// none (see [`Joint::thermal_align`]). By measurement the paper's term is kept at the largest
/// weight that costs nothing: on the simulated low-light scene (`s3tir-firmware-sim scene
/// --rgb-scale 4 --low-light`, 32×24 thermal, 800 iterations with 80 of RGB pre-training, seed
/// 1, CPU; 2026-11-29) the held-out thermal at 4× is 25.77 dB without it, 25.78 dB at 0.05
/// (its position gradient 0.028× the other terms', median of 13 samples), 25.49 dB at 0.5
/// (0.30×; depth error at the RGB cameras 100 → 112 mm) and 23.20 dB at 5 (3.3×; 167 mm); with
/// the default quarter of pre-training 25.98 dB on and off. No weight measured helps.
pub const DEFAULT_THERMAL_ALIGN: f64 = 0.05;

/// The CLI's RGB pre-training when none is given: this fraction of the run's iterations (of
/// the nominal run's schedule under a time budget). By measurement on the simulated low-light
/// scene (800 iterations, seeds 1 and 2, thermal at 4× against the truth; 2026-11-29):
/// none 25.63 / 25.59 dB (depth coverage 81 / 82 %), a tenth 25.78 / 25.83 dB (90 / 91 %), a
/// quarter 25.98 / 25.89 dB (97 / 96 %), half 25.94 / 25.98 dB (99 / 97 %) but a larger depth
/// error at the RGB cameras (114 / 110 mm against 102 / 99 mm at a quarter).
pub const DEFAULT_RGB_PRETRAIN_FRACTION: f64 = 0.25;

/// Joint RGB + thermal training on shared geometry (TGA-GS, paper §3.3–3.4). Inert in a run
/// without RGB views, except `thermal_align` when set explicitly.
///
/// Every primitive has its S³-TIR thermal radiance and an SH colour; a thermal view and an
/// RGB view each supervise through their own camera (pose, intrinsics, resolution), so the
/// geometry the RGB views sharpen is the geometry the thermal head is rendered with.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Joint {
    /// After the RGB pre-training every step trains a view together with its partner of the
    /// other modality (the other camera's image of the same instant: the nearest overlapping
    /// camera; one optimiser step on the sum of both losses, as the paper's end-to-end phase),
    /// so a joint iteration supervises both heads. Off: each step trains one drawn view.
    pub pair_steps: bool,
    /// RGB pre-training: the first this-many iterations (of the schedule: a fraction of a
    /// time budget) train on RGB views only, then every view trains (paper §3.3). Counted
    /// inside the run's iterations, as the paper keeps its total at 30 k. Ignored without RGB
    /// views. The CLI's default is [`DEFAULT_RGB_PRETRAIN_FRACTION`] of the iterations.
    pub rgb_pretrain: u64,
    /// Multiplies every term of a thermal view's loss.
    pub thermal_weight: f64,
    /// Multiplies every term of an RGB view's loss.
    pub rgb_weight: f64,
    pub rgb_loss: RgbLoss,
    /// ε of L1-low (paper: 10⁻³, after Aleth-NeRF).
    pub l1_low_eps: f64,
    /// Weight of the thermal gradient alignment loss ([`crate::loss::align`]) on thermal views
    /// after the RGB pre-training; `None`: [`DEFAULT_THERMAL_ALIGN`] when the run has RGB
    /// views, 0 otherwise (thermal-only runs keep their loss unless asked); 0 turns it off.
    pub thermal_align: Option<f64>,
    /// Super-resolved thermal renders of the held-out thermal views (`renders_sr/`) at this
    /// factor; `None`: the RGB camera's resolution over the thermal camera's (rounded) in a
    /// run with both, none otherwise; 1: none.
    pub sr_scale: Option<usize>,
}

impl Default for Joint {
    fn default() -> Self {
        Self {
            pair_steps: true,
            rgb_pretrain: 0,
            thermal_weight: 1.0,
            rgb_weight: 1.0,
            rgb_loss: RgbLoss::Auto,
            l1_low_eps: 1e-3,
            thermal_align: None,
            sr_scale: None,
        }
    }
}

/// Default [`Densify::relocate_frac`]: chosen by measurement (see the module docs of
/// `train::density`).
pub const RELOCATE_FRAC: f64 = 0.0;

/// Default [`Densify::grow_frac`]: chosen by measurement (see the module docs of
/// `train::density`).
pub const GROW_FRAC: f64 = 0.05;

/// Density control: 3DGS-style clone/split/prune under a **hard primitive budget**, growth
/// capped per round (`grow_frac`), optional relocation when the budget is full.
///
/// Every `every` iterations while the schedule is in `[from, min(until, iters/2))` (see the
/// `schedule` module for time-budgeted runs): primitives whose mean view-space positional
/// gradient — 3DGS's statistic, the gradient with respect to the projected centre in
/// normalised device coordinates (`train::view_space_gradient`) — exceeds `grad_threshold`
/// (3DGS's 2e-4) are densified — split in two (scales ÷ 1.6, centres drawn from the primitive)
/// when their largest scale exceeds `split_scale_frac` × the scene extent, cloned otherwise —
/// highest gradients first, at most `grow_frac` × the count more per round, and only while
/// the count stays ≤ the budget (with `relocate_frac` > 0 a full budget gives the weakest
/// primitives' places to the candidates beyond it); then primitives with
/// opacity < `prune_opacity` are removed. Initialisation never exceeds the budget either
/// (points are subsampled). Each round's figures are in `capacity.json` (`densify_rounds`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Densify {
    pub from: u64,
    pub until: u64,
    pub every: u64,
    pub grad_threshold: f64,
    pub split_scale_frac: f64,
    pub prune_opacity: f64,
    /// With the budget full, up to this fraction of the primitives per round — the weakest,
    /// by opacity — are removed to make room for candidates beyond the budget. Configs saved
    /// before it existed read 0 (no relocation), so resumed runs keep their behaviour.
    #[serde(default)]
    pub relocate_frac: f64,
    /// At most this fraction of the primitives added per round (0: up to the budget). Configs
    /// saved before it existed read 0.
    #[serde(default)]
    pub grow_frac: f64,
}

impl Default for Densify {
    fn default() -> Self {
        Self {
            from: 500,
            until: 15_000,
            every: 100,
            grad_threshold: 2e-4,
            split_scale_frac: 0.01,
            prune_opacity: 0.005,
            relocate_frac: RELOCATE_FRAC,
            grow_frac: GROW_FRAC,
        }
    }
}

/// Default λ of the band amplitudes' L1 step (see [`Capacity::band_l1`]), by measurement at
/// equal time (3 minutes, Vulkan on lavapipe, one seed; held-out PSNR / LPIPS at the end):
/// on the simulated facade at 640×512 (`s3tir-firmware-sim scene --layout facade`, 40 views)
/// all bands kept 25.93 dB / 0.427, λ = 5e-5 26.11 / 0.434 (297 of 2 100 primitives keep
/// bands), λ = 2e-4 26.60 / 0.442 (17 keep them), 3dgs mode 26.54 / 0.447; on thermal-facade
/// (real, 320×240) all bands 16.91 / 0.623, λ = 5e-5 and 2e-4 both 17.31 (no band left:
/// the run ends band-free) / 0.635 and 0.626, 3dgs mode 17.40 / 0.615. λ = 5e-5 keeps the
/// bands on the textured scene and none on the real facade.
pub const BAND_L1: f64 = 5e-5;
/// Default share of primitives that may keep bands (see [`Capacity::band_budget`]).
pub const BAND_BUDGET: f64 = 0.5;

/// Capacity adaptation: bands whose amplitude stays below `band_amp_threshold` (normalised
/// intensity units) are dropped, checked every `every` iterations after the warm-up; one pass
/// over the training views after it the bands are granted (kept) only where they pay
/// (`band_l1`, `band_budget`; see `train::bands`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Capacity {
    pub band_amp_threshold: f64,
    pub every: u64,
    /// λ of the band amplitudes' proximal L1 step (`train::adam`), in gradient units of the
    /// loss: an amplitude whose mean gradient stays below it goes to exactly zero and is
    /// dropped. Also the grant's threshold: a primitive keeps its bands at the grant only
    /// when a band's RMS gradient exceeds it. 0: no L1 step, every primitive may be granted.
    /// A run whose config.json predates it resumes as it was trained: 0 (and budget 1).
    #[serde(default)]
    pub band_l1: f64,
    /// Fraction of the primitives that may keep bands at the grant (the highest RMS band
    /// gradients first); 1: no budget.
    #[serde(default = "Capacity::default_band_budget")]
    pub band_budget: f64,
    /// β below this (and no bands) counts as "Gaussian path".
    pub gaussian_beta_max: f64,
    /// Minimum camera-overlap fraction for a consistency pair.
    pub min_pair_overlap: f64,
}

impl Capacity {
    /// A config.json without `band_budget` predates the grant: no budget (see `band_l1`).
    fn default_band_budget() -> f64 {
        1.0
    }
}

impl Default for Capacity {
    fn default() -> Self {
        Self {
            band_amp_threshold: 1e-3,
            every: 1000,
            band_l1: BAND_L1,
            band_budget: BAND_BUDGET,
            gaussian_beta_max: 2.05,
            min_pair_overlap: 0.5,
        }
    }
}

/// Where the consistency term's second view (the partner) comes from.
///
/// The paper (eq. 5) warps view i's frequency maps into a partner view j; it does not say how
/// the pair is scheduled. Rendering the partner in the same step ([`ConsistPartner::Render`])
/// costs a second projection, sort, forward and backward pass: at least 2× the step of a
/// 3DGS view however the kernels are tuned, while full S³-TIR training is meant to cost at most
/// 1.5× 3DGS mode. [`ConsistPartner::Previous`] (the default) pairs consecutive steps
/// instead: a step on a random view i is followed by a step on a random view j that overlaps
/// i, whose term warps j into the G-buffers kept from step i's render (one optimiser step old,
/// under stop-gradient). Nothing extra is rendered; the term is computed on every second step
/// and pulls only the freshly rendered side. `s3tir-train bench` measures both modes' steps/s
/// (`--consist-partner render` gives the other schedule to compare held-out quality).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ConsistPartner {
    /// The previous step's training view, from the G-buffers kept from its render (the
    /// schedule alternates a random view and a view overlapping it). No extra render.
    #[default]
    Previous,
    /// The view's overlap partner, rendered in the same step (both views get gradients).
    Render,
}

impl fmt::Display for ConsistPartner {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ConsistPartner::Previous => "previous",
            ConsistPartner::Render => "render",
        })
    }
}

impl FromStr for ConsistPartner {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "previous" => Ok(ConsistPartner::Previous),
            "render" => Ok(ConsistPartner::Render),
            other => Err(format!(
                "unknown consistency partner `{other}` (expected previous or render)"
            )),
        }
    }
}

/// The compute backend a run trains (or a command renders) on: `cpu`, the reference renderer
/// in Rust, or `vulkan`, the on-rig compute trainer (feature `vulkan`). `--backend` takes these
/// names and `config.json` stores them as strings (`"cpu"`, `"vulkan"`), as it always has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
#[value(rename_all = "lowercase")]
pub enum BackendKind {
    #[default]
    Cpu,
    Vulkan,
}

impl BackendKind {
    /// The name `--backend` and `config.json` use.
    pub fn as_str(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Vulkan => "vulkan",
        }
    }
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Everything a run is configured by.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Dataset folder.
    pub data: PathBuf,
    pub load: LoadOptions,
    pub mode: Mode,
    /// Iterations; with `time_budget_s` the nominal length the schedule is written in.
    pub iters: u64,
    /// Training-time budget (seconds of step time): the run stops when it is spent and the
    /// schedule (warm-up, densification window, learning-rate decay) follows the fraction
    /// spent instead of iterations (configs written before this option read as none).
    #[serde(default)]
    pub time_budget_s: Option<f64>,
    /// Gaussian warm-up: β ≡ 2 and bands off until this iteration (paper: 3000).
    pub warmup: u64,
    /// After the warm-up, the band learning rates rise linearly from 0 to their value over this
    /// many iterations of the nominal run (0: all at once, as in the paper — the default, see
    /// `train/schedule.rs`; configs written before this option read as 0).
    #[serde(default)]
    pub band_ramp: u64,
    /// Gabor bands per primitive in modes with bands (paper: M = 4).
    pub bands: usize,
    /// Hard primitive budget.
    pub budget: usize,
    pub seed: u64,
    pub consist: bool,
    pub sparse: bool,
    pub smooth: bool,
    pub weights: Weights,
    /// Base learning rates; `means` is multiplied by the scene extent and decays exponentially to
    /// `means_lr_final_ratio` × itself over the run (3DGS).
    pub lr: GroupLrs,
    pub means_lr_final_ratio: f64,
    pub densify: Densify,
    pub capacity: Capacity,
    /// Consistency loss every k-th iteration (with [`ConsistPartner::Render`] it renders a
    /// second view).
    pub consist_every: u64,
    /// Where the consistency partner's G-buffers come from (configs written before this
    /// option existed read as the default).
    #[serde(default)]
    pub consist_partner: ConsistPartner,
    /// Held-out evaluation interval, training seconds (also at the start and the end).
    pub eval_every_s: f64,
    /// Checkpoint interval, training seconds (also at the end and on Ctrl-C).
    pub checkpoint_every_s: f64,
    /// Initial opacity.
    pub init_opacity: f64,
    /// SH degree of the colour branch when the data have RGB.
    pub sh_degree: usize,
    /// The backend the run trains on.
    pub backend: BackendKind,
    /// Per-view radiometric response learned with the scene (configs written before this
    /// option read as the default, `auto`).
    #[serde(default)]
    pub response: super::ResponseConfig,
    /// Time the CPU reference renderer's step with and without its shortcuts when the outputs
    /// are written (`capacity.json`: `cpu_step_ms_*`): six CPU passes over a training view, so
    /// off unless asked for (`--cpu-timing`).
    #[serde(default)]
    pub cpu_timing: bool,
    /// Joint RGB + thermal training (configs written before it read as the default).
    #[serde(default)]
    pub joint: Joint,
}

impl TrainConfig {
    /// Every option's default, `data` empty: what the command line shows in `--help` and falls
    /// back to. With [`TrainConfig::new`] (and the option types' own `Default`s it uses) the one
    /// place a training default is declared. The command line keeps its own options struct
    /// (`cli/train_args.rs`) rather than parsing into this one because `--resume` must tell an
    /// option not given from one given as its default (`--iters`, `--backend`: the run's own
    /// values then hold); it reads every default from here.
    pub fn defaults() -> &'static TrainConfig {
        static DEFAULTS: OnceLock<TrainConfig> = OnceLock::new();
        DEFAULTS.get_or_init(|| TrainConfig::new(PathBuf::new()))
    }

    /// Paper defaults (§4.1) for a dataset.
    pub fn new(data: PathBuf) -> Self {
        Self {
            data,
            load: LoadOptions::default(),
            mode: Mode::S3tir,
            iters: 30_000,
            time_budget_s: None,
            warmup: 3_000,
            band_ramp: 0,
            bands: crate::primitive::DEFAULT_BANDS,
            budget: 100_000,
            seed: 0,
            consist: true,
            sparse: true,
            smooth: true,
            weights: Weights::default(),
            lr: GroupLrs {
                // 3DGS's position lr (× scene extent), scaling, rotation, opacity, DC colour.
                means: 1.6e-4,
                log_scales: 5e-3,
                quats: 1e-3,
                opacity_logits: 5e-2,
                // The paper's β lr, in β units (see `adam`).
                beta: 1e-3,
                // ω_low is the thermal value itself (normalised), the analogue of 3DGS's DC
                // colour (lr 0.0025 on SH DC ≈ 0.0007 on the colour); 0.0025 directly.
                omega_low: 2.5e-3,
                band_amp: 2.5e-3,
                band_freq: 1e-2,
                band_phase: 1e-2,
                sh: 2.5e-3,
            },
            means_lr_final_ratio: 0.01,
            densify: Densify::default(),
            capacity: Capacity::default(),
            consist_every: 1,
            consist_partner: ConsistPartner::default(),
            eval_every_s: 30.0,
            checkpoint_every_s: 60.0,
            init_opacity: 0.1,
            sh_degree: 0,
            backend: BackendKind::Cpu,
            response: super::ResponseConfig::default(),
            cpu_timing: false,
            joint: Joint::default(),
        }
    }
}
