//! The training loop: schedule, losses, Adam, density control, capacity adaptation,
//! evaluation against wall time, checkpoints and outputs — written against [`Backend`] so the
//! Vulkan backend plugs into the same loop.
//!
//! # Schedule (paper §4.1)
//! Iterations `< warmup`: Gaussian warm-up — β frozen at exactly 2 (`beta_raw` =
//! [`BETA_RAW_FROZEN`], so the renderer takes the cheap Gaussian path) and band amplitudes
//! held at 0 (band lrs 0), only the photometric loss. At the warm-up's end, in modes that learn β,
//! every frozen β is released to [`BETA_RAW_GAUSSIAN`] (β = 2 + 4.5e-5, learnable); in 3dgs and
//! gabor modes β stays frozen for the whole run. From `warmup` on, in the modes that have
//! them, β and the bands train, and `L_sparse` (Ψ_high), `L_smooth` (TV of Ψ_β) and
//! `L_consist` (Ψ_high, Ψ_β warped to the view's overlap partner) join the loss. A term whose
//! G-buffer cannot change in the mode (e.g. `L_sparse` without bands) is not computed.
//!
//! # Consistency pairs over steps ([`ConsistPartner`])
//! With `previous` (the default) no step renders a second view: a step on a random view i
//! ("lead", no term) keeps its G-buffers (the host's copy on the host path, the backend's on
//! its device path), and the next step ("follow") trains a random view j among those that
//! overlap i (≥ `capacity.min_pair_overlap`; not only i's best partner, which would leave
//! the views that are nobody's best partner to the lead steps) with `L_consist`
//! warping j into i's kept G-buffers (rendered one optimiser step earlier, under
//! stop-gradient); then a lead again. The term runs on every second step (at most; also only
//! on iterations that are multiples of `consist_every`) and pulls the freshly rendered side
//! only. Density control, band dropping, β freezing and the end of the warm-up drop the kept
//! view (it shows the primitives before the change), so the next step leads. With `render`
//! every step renders i's partner j too (G-buffers only) and both get the term's gradients.
//!
//! # Leaving out what the scene does not need
//! - colour (SH) is allocated only when a view has RGB;
//! - consistency pairs are chosen once by camera overlap (fraction of a 6×6 grid of the view's
//!   rays, cut at the scene-centre depth, that land inside the other image, ≥
//!   `capacity.min_pair_overlap`); views without a partner skip the term, and with no pair at all
//!   it is never computed;
//! - every `capacity.every` iterations after the warm-up, bands with `|ω_j| <
//!   band_amp_threshold` are dropped per primitive (zeroed), each primitive's live bands are
//!   moved to its first slots and the rest marked dropped (`band_count`, saved in checkpoints
//!   and the PLY): the renderer skips dropped slots and Adam never updates them, so they cannot
//!   grow back. The band storage of the whole set compacts to the largest live count (M shrinks);
//! - at the same check, in modes that learn β, primitives with β ≤ `gaussian_beta_max` and no
//!   live band are snapped to β = 2 exactly and frozen ([`BETA_RAW_FROZEN`]): from then on the
//!   renderer evaluates them on the cheap Gaussian path (no `pow`, no bands, no β gradient; see
//!   [`crate::render`]). The report ([`CapacityReport`]) says all of this with the memory saved
//!   and the CPU reference renderer's step time with and without the shortcuts, measured on a
//!   training view when the outputs are written.
//!
//! # Scales and aliasing
//! The renderer point-samples pixel centres, so primitives smaller than a pixel footprint can
//! fall between samples and stop receiving gradients; scales are clamped from below to half the
//! pixel footprint at the median scene depth after every step.

pub mod adam;
pub mod backend;
pub mod config;
pub mod params;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use adam::{AdamParams, AdamState, GroupLrs};
pub use backend::{
    Backend, CpuBackend, DeviceStep, DeviceStepResult, OptimiserState, Partner, ResidentStep,
    RunShape,
};
pub use config::{Capacity, ConsistPartner, Densify, Mode, TrainConfig, Weights};

use crate::camera::PinholeCamera;
use crate::checkpoint::{self, CHECKPOINT_VERSION, Checkpoint, CheckpointError};
use crate::dataset::{Dataset, DatasetError};
use crate::error::TrainerError;
use crate::loss::consistency::{ConsistencyOptions, consistency_loss};
use crate::loss::photometric::l1_dssim;
use crate::loss::{LossWeights, view_loss};
use crate::metrics::{EvalSummary, view_metrics};
use crate::ply::PlyError;
use crate::primitive::{
    BETA_RAW_FROZEN, BETA_RAW_GAUSSIAN, PrimitiveInit, Primitives, beta_of_raw, is_beta_frozen,
};
use crate::render::GBuffers;
use crate::report::{self, MetricsRow, ReportError};

/// Files of a run folder.
pub mod files {
    pub const CONFIG: &str = "config.json";
    pub const CHECKPOINT: &str = "checkpoint.json";
    pub const METRICS_CSV: &str = "metrics.csv";
    pub const METRICS_PNG: &str = "error_vs_time.png";
    pub const PLY: &str = "point_cloud.ply";
    pub const EVAL: &str = "eval.json";
    pub const CAPACITY: &str = "capacity.json";
    pub const BETA_HIST: &str = "beta_hist.png";
    pub const RENDERS: &str = "renders";
    pub const GBUFFERS: &str = "gbuffers";
}

#[derive(Debug, Error)]
pub enum TrainError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Render(#[from] TrainerError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Ply(#[from] PlyError),
    #[error(transparent)]
    Report(#[from] ReportError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("configuration: {reason}")]
    Config { reason: String },
    #[error("run {run_dir}: {reason}")]
    Run { run_dir: PathBuf, reason: String },
    /// A step's loss is NaN or infinite: the run stops before anything is saved from it.
    #[error(
        "run {run_dir}: iteration {iteration}: the loss is {loss} (the run diverged); stopped \
         without saving this state: the last checkpoint is intact, `--resume` continues from it \
         (lower the learning rates if it recurs)"
    )]
    NonFinite {
        run_dir: PathBuf,
        iteration: u64,
        loss: f64,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What the loop reports as it goes (the CLI draws it).
#[derive(Debug, Clone)]
pub enum Event {
    Step { iteration: u64, loss: f64 },
    Eval(MetricsRow),
    Checkpoint { iteration: u64 },
}

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Finished,
    /// Stopped by the stop flag after writing a checkpoint.
    Interrupted {
        iteration: u64,
    },
}

/// What capacity adaptation left out and what it saved.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CapacityReport {
    pub mode: String,
    pub colour_allocated: bool,
    pub colour_reason: String,
    pub consistency_pairs: usize,
    pub consistency_reason: String,
    pub bands_initial: usize,
    pub bands_now: usize,
    /// Bands dropped at the last check (sum over primitives).
    pub bands_dropped_total: usize,
    /// Dropped band slots still in storage (below M, above a primitive's live count): the
    /// renderer skips them and Adam never updates them.
    #[serde(default)]
    pub band_slots_dropped: usize,
    /// Bytes freed by band compaction (parameters and both Adam moments).
    pub band_bytes_saved: usize,
    /// Primitives on the cheap Gaussian path (β exactly 2 and frozen, no live band).
    pub gaussian_path_primitives: usize,
    /// Primitives snapped to β = 2 and frozen by the last check.
    #[serde(default)]
    pub gaussian_frozen_last_check: usize,
    /// CPU reference renderer, forward + backward of one training view at the end of the run:
    /// with the shortcuts (cheap Gaussian path, dropped slots skipped) and with every primitive
    /// forced through the general path (ms, best of 3).
    #[serde(default)]
    pub cpu_step_ms_with_shortcuts: Option<f64>,
    #[serde(default)]
    pub cpu_step_ms_general_path: Option<f64>,
    pub primitives: usize,
    pub memory_bytes: usize,
    /// Mean step time before and after the last band compaction (ms).
    pub step_ms_before_compaction: Option<f64>,
    pub step_ms_after_compaction: Option<f64>,
    pub notes: Vec<String>,
}

/// Loop state that is not parameters (kept in checkpoints).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct LoopState {
    capacity: CapacityReport,
    last_eval_s: f64,
    last_checkpoint_s: f64,
    loss_sum: f64,
    loss_count: u64,
    step_ms_sum: f64,
    step_count: u64,
}

/// A training run on a backend.
#[derive(Debug)]
pub struct Trainer<B: Backend> {
    pub cfg: TrainConfig,
    pub data: Dataset,
    pub backend: B,
    pub run_dir: PathBuf,
    pub prims: Primitives<f32>,
    pub adam: AdamState,
    pub iteration: u64,
    pub train_seconds: f64,
    extent_m: f64,
    min_log_scale: f32,
    /// Overlap partner of each view (index into `data.views`).
    pairs: Vec<Option<usize>>,
    /// Each training view's overlapping training views (overlap ≥ `min_pair_overlap`).
    neighbours: Vec<Vec<usize>>,
    grad_accum: Vec<f64>,
    grad_count: Vec<u32>,
    /// The optimiser state (`prims`' values, `adam`'s moments, the densification statistics)
    /// lives on the backend's device; the host copies are stale until [`Trainer::sync_host`].
    resident: bool,
    /// The last step's training view, kept for a [`ConsistPartner::Previous`] term in the next
    /// step (cleared whenever the primitives change between steps).
    kept: Option<KeptView>,
    state: LoopState,
}

/// A training view's G-buffers kept from its step for the next step's consistency term.
#[derive(Debug)]
struct KeptView {
    view: usize,
    /// Iteration of the step that rendered it.
    iteration: u64,
    /// That step itself had a consistency term (it followed another): the next step draws a
    /// fresh view instead of following it, so the schedule alternates.
    followed: bool,
    /// The host's copy (host path); `None`: the backend's device keeps them
    /// ([`Backend::device_step`]).
    gbuffers: Option<GBuffers<f32>>,
}

/// The consistency partner a step uses (index into `data.views`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PairChoice {
    /// Rendered in this step.
    Render(usize),
    /// The previous step's training view, from its kept G-buffers.
    Previous(usize),
}

impl PairChoice {
    fn view(self) -> usize {
        match self {
            PairChoice::Render(v) | PairChoice::Previous(v) => v,
        }
    }
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// The largest work a run of `cfg` on `data` gives its backend ([`Backend::check_run`]).
fn run_shape(cfg: &TrainConfig, data: &Dataset) -> RunShape {
    let largest =
        |f: fn(&PinholeCamera) -> usize| data.views.iter().map(|v| f(&v.camera)).max().unwrap_or(0);
    RunShape {
        budget: cfg.budget,
        bands: if cfg.mode.has_bands() { cfg.bands } else { 0 },
        width: largest(|c| c.width),
        height: largest(|c| c.height),
    }
}

impl<B: Backend> Trainer<B> {
    /// A new run: initial primitives from the dataset, run folder created, config written.
    pub fn new(
        cfg: TrainConfig,
        data: Dataset,
        backend: B,
        run_dir: &Path,
    ) -> Result<Self, TrainError> {
        if cfg.budget == 0 {
            return Err(TrainError::Config {
                reason: "--budget must be at least 1".into(),
            });
        }
        if !data.has_thermal() && !data.has_rgb() {
            return Err(TrainError::Config {
                reason: "the dataset has neither thermal nor RGB views".into(),
            });
        }
        // Before anything is written: the run must fit the backend (device limits).
        backend.check_run(&run_shape(&cfg, &data))?;
        if run_dir.join(files::CHECKPOINT).exists() {
            return Err(TrainError::Run {
                run_dir: run_dir.to_path_buf(),
                reason: "already holds a run (checkpoint.json): continue it with --resume or \
                         choose another --out"
                    .into(),
            });
        }
        std::fs::create_dir_all(run_dir).map_err(io_err(run_dir))?;
        // A log from an unfinished start (no checkpoint yet) must not mix with this run; it is
        // moved aside (`metrics.csv.1`, `.2`, …), never deleted.
        let csv = run_dir.join(files::METRICS_CSV);
        if csv.exists() {
            let aside = (1..)
                .map(|k| run_dir.join(format!("{}.{k}", files::METRICS_CSV)))
                .find(|p| !p.exists())
                .unwrap_or_else(|| run_dir.join(format!("{}.old", files::METRICS_CSV)));
            std::fs::rename(&csv, &aside).map_err(io_err(&csv))?;
            tracing::warn!(
                from = %csv.display(),
                to = %aside.display(),
                "the folder held a metrics log without a checkpoint (an unfinished start): kept aside"
            );
        }
        let cfg_path = run_dir.join(files::CONFIG);
        let json = serde_json::to_string_pretty(&cfg).map_err(|e| TrainError::Config {
            reason: e.to_string(),
        })?;
        std::fs::write(&cfg_path, json).map_err(io_err(&cfg_path))?;
        let mut t = Self::bare(cfg, data, backend, run_dir);
        t.prims = t.initial_primitives();
        t.adam = AdamState::new(&t.prims);
        t.state.capacity = t.initial_capacity();
        Ok(t)
    }

    /// Continues the run in `run_dir` from its checkpoint (`cfg` normally read from its
    /// `config.json`; `cfg.iters` may be raised).
    pub fn resume(
        cfg: TrainConfig,
        data: Dataset,
        backend: B,
        run_dir: &Path,
    ) -> Result<Self, TrainError> {
        backend.check_run(&run_shape(&cfg, &data))?;
        let ck = checkpoint::load(&run_dir.join(files::CHECKPOINT))?;
        let mut t = Self::bare(cfg, data, backend, run_dir);
        t.prims = ck.primitives.into();
        t.adam = AdamState {
            m: ck.adam_m.into(),
            v: ck.adam_v.into(),
            step: ck.adam_step,
        };
        t.iteration = ck.iteration;
        t.train_seconds = ck.train_seconds;
        t.state = serde_json::from_value(ck.state).unwrap_or_default();
        t.grad_accum = vec![0.0; t.prims.len()];
        t.grad_count = vec![0; t.prims.len()];
        tracing::info!(iteration = t.iteration, "resumed from checkpoint");
        Ok(t)
    }

    fn bare(cfg: TrainConfig, data: Dataset, backend: B, run_dir: &Path) -> Self {
        // Scene extent as 3DGS: 1.1 × the largest camera distance from the cameras' centroid.
        let centres: Vec<[f64; 3]> = data.views.iter().map(|v| v.camera.centre_world()).collect();
        let n = centres.len().max(1) as f64;
        let c = [0, 1, 2].map(|a| centres.iter().map(|p| p[a]).sum::<f64>() / n);
        let radius = centres
            .iter()
            .map(|p| ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        let (lo, hi) = data.bounds_m();
        let scene_diag =
            ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
        let extent_m = (1.1 * radius).max(0.1 * scene_diag).max(1e-3);
        // Median scene depth over the views → pixel footprint.
        let centre = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
        let depth = median(
            data.views
                .iter()
                .map(|v| v.camera.to_cam(centre)[2].abs())
                .collect(),
        )
        .unwrap_or(1.0);
        let f = median(data.views.iter().map(|v| v.camera.fx_px).collect()).unwrap_or(1.0);
        let min_log_scale = (0.5 * depth / f).max(1e-9).ln() as f32;
        let (pairs, neighbours) = choose_pairs(&data, centre, cfg.capacity.min_pair_overlap);
        Self {
            cfg,
            data,
            backend,
            run_dir: run_dir.to_path_buf(),
            prims: Primitives::new(0, None),
            adam: AdamState::new(&Primitives::new(0, None)),
            iteration: 0,
            train_seconds: 0.0,
            extent_m,
            min_log_scale,
            pairs,
            neighbours,
            grad_accum: Vec::new(),
            grad_count: Vec::new(),
            resident: false,
            kept: None,
            state: LoopState::default(),
        }
    }

    fn bands_for_mode(&self) -> usize {
        if self.cfg.mode.has_bands() {
            self.cfg.bands
        } else {
            0
        }
    }

    fn initial_primitives(&mut self) -> Primitives<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ 0x5eed_1417);
        let sh = self.data.has_rgb().then_some(self.cfg.sh_degree);
        let mut prims = Primitives::<f64>::new(self.bands_for_mode(), sh);
        let mut pts: Vec<([f64; 3], [u8; 3])> = self
            .data
            .points_m
            .iter()
            .copied()
            .zip(self.data.point_rgb.iter().copied())
            .collect();
        let (lo, hi) = self.data.bounds_m();
        if pts.is_empty() {
            let n = self.cfg.budget.min(10_000);
            pts = (0..n)
                .map(|_| {
                    (
                        [0, 1, 2].map(|a| rng.random_range(lo[a]..=hi[a].max(lo[a] + 1e-9))),
                        [128; 3],
                    )
                })
                .collect();
        }
        // Hard budget: subsample (seeded partial shuffle).
        if pts.len() > self.cfg.budget {
            for i in 0..self.cfg.budget {
                let j = rng.random_range(i..pts.len());
                pts.swap(i, j);
            }
            pts.truncate(self.cfg.budget);
        }
        let positions: Vec<[f64; 3]> = pts.iter().map(|p| p.0).collect();
        let nn = knn3_mean_distance(&positions, lo, hi);
        let min_scale = f64::from(self.min_log_scale).exp();
        for (k, (p, rgb)) in pts.iter().enumerate() {
            // 3DGS initialises σ to the mean distance to the 3 nearest points; our kernel has no
            // ½, so s = √2·σ gives the same footprint.
            let s = (nn[k] * std::f64::consts::SQRT_2).max(min_scale);
            let bands = (0..prims.bands)
                .map(|_| {
                    let d = random_unit(&mut rng);
                    let f = rng.random_range(0.5..2.0) / (4.0 * s);
                    (
                        0.0,
                        [d[0] * f, d[1] * f, d[2] * f],
                        rng.random_range(0.0..std::f64::consts::TAU),
                    )
                })
                .collect();
            let c0 = crate::ply::SH_C0;
            prims.push(&PrimitiveInit {
                mean_m: *p,
                scale_m: [s; 3],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity: self.cfg.init_opacity,
                beta: 2.0,
                omega_low: self.data.thermal_at(*p).map_or(0.5, f64::from),
                bands,
                sh: vec![rgb.map(|c| (f64::from(c) / 255.0 - 0.5) / c0)],
            });
        }
        let mut prims = prims.cast::<f32>();
        // β ≡ 2 during the warm-up (and for the whole run in modes without learnable β): frozen
        // on the cheap Gaussian path; released at the warm-up's end (see `step`).
        if !self.cfg.mode.learns_beta() || self.cfg.warmup > 0 {
            prims.beta_raw.fill(BETA_RAW_FROZEN as f32);
        }
        self.grad_accum = vec![0.0; prims.len()];
        self.grad_count = vec![0; prims.len()];
        prims
    }

    fn initial_capacity(&self) -> CapacityReport {
        let pairs = self.pairs.iter().filter(|p| p.is_some()).count();
        let has_rgb = self.data.has_rgb();
        let mut notes = Vec::new();
        if !self.data.undistorted_models.is_empty() {
            notes.push(format!(
                "undistorted at load: {}",
                self.data.undistorted_models.join(", ")
            ));
        }
        CapacityReport {
            mode: self.cfg.mode.to_string(),
            colour_allocated: has_rgb,
            colour_reason: if has_rgb {
                "the dataset has RGB views".into()
            } else {
                "no RGB views: no SH colour allocated".into()
            },
            consistency_pairs: pairs,
            consistency_reason: if !self.cfg.consist {
                "disabled (--no-consist)".into()
            } else if !(self.cfg.mode.learns_beta() || self.cfg.mode.has_bands()) {
                "not needed: Ψ_high and Ψ_β are constant in this mode".into()
            } else if pairs == 0 {
                "skipped: no view pair overlaps enough".into()
            } else {
                format!("{pairs} views have an overlap partner")
            },
            bands_initial: self.prims.bands,
            bands_now: self.prims.bands,
            notes,
            ..CapacityReport::default()
        }
    }

    /// Bytes of parameters plus the two Adam moments (each with its copy of the band mask).
    pub fn memory_bytes(&self) -> usize {
        3 * 4 * (params::value_count(&self.prims) + self.prims.band_count.len())
    }

    fn after_warmup(&self) -> bool {
        self.iteration >= self.cfg.warmup
    }

    fn lrs(&self) -> GroupLrs {
        let mut lr = self.cfg.lr;
        let t = (self.iteration as f64 / self.cfg.iters.max(1) as f64).clamp(0.0, 1.0);
        lr.means *= self.extent_m * self.cfg.means_lr_final_ratio.powf(t);
        let warm = self.after_warmup();
        if !(self.cfg.mode.learns_beta() && warm) {
            lr.beta = 0.0;
        }
        if !(self.prims.bands > 0 && warm) {
            lr.band_amp = 0.0;
            lr.band_freq = 0.0;
            lr.band_phase = 0.0;
        }
        lr
    }

    fn loss_weights(&self) -> LossWeights {
        let warm = self.after_warmup();
        LossWeights {
            lambda_dssim: self.cfg.weights.dssim,
            lambda_consist: self.cfg.weights.consist,
            lambda_sparse: if warm && self.cfg.sparse && self.prims.bands > 0 {
                self.cfg.weights.sparse
            } else {
                0.0
            },
            lambda_smooth: if warm && self.cfg.smooth && self.cfg.mode.learns_beta() {
                self.cfg.weights.smooth
            } else {
                0.0
            },
        }
    }

    fn consist_active(&self) -> bool {
        self.cfg.consist
            && self.after_warmup()
            && (self.cfg.mode.learns_beta() || self.prims.bands > 0)
            && self.cfg.consist_every > 0
            && self.iteration.is_multiple_of(self.cfg.consist_every)
    }

    /// The view of a step and its consistency partner, from the view `drawn` at random (see
    /// [`ConsistPartner`]): with [`ConsistPartner::Previous`], a step that follows a step
    /// without a term (on view i, whose G-buffers are kept) trains one of i's overlapping
    /// views j, drawn from `rng`, against them instead of `drawn`.
    fn schedule(&self, drawn: usize, rng: &mut ChaCha8Rng) -> (usize, Option<PairChoice>) {
        if !self.consist_active() {
            return (drawn, None);
        }
        match self.cfg.consist_partner {
            ConsistPartner::Render => (drawn, self.pairs[drawn].map(PairChoice::Render)),
            ConsistPartner::Previous => match &self.kept {
                // One of i's overlapping views at random, not i's best partner: views that are
                // nobody's best partner would otherwise train only on lead steps.
                Some(k) if !k.followed && k.iteration + 1 == self.iteration => {
                    match self.neighbours[k.view].as_slice() {
                        [] => (drawn, None),
                        near => (
                            near[rng.random_range(0..near.len())],
                            Some(PairChoice::Previous(k.view)),
                        ),
                    }
                }
                _ => (drawn, None),
            },
        }
    }

    /// Records the step's training view `vi` as kept for the next step (`gbuffers`: the host's
    /// copy; `None`: the backend's device keeps them).
    fn keep(&mut self, vi: usize, followed: bool, gbuffers: Option<GBuffers<f32>>) {
        self.kept = Some(KeptView {
            view: vi,
            iteration: self.iteration,
            followed,
            gbuffers,
        });
    }

    /// Loss and upstream gradient of one view's own terms.
    fn view_terms(
        &self,
        vi: usize,
        gb: &GBuffers<f32>,
        weights: &LossWeights,
        up: &mut GBuffers<f32>,
    ) -> Result<f64, TrainError> {
        let view = &self.data.views[vi];
        let mut loss = 0.0;
        if let Some(target) = &view.thermal {
            loss += view_loss(gb, target, weights, up)?.total;
        }
        if let (Some(target), false) = (&view.rgb, gb.rgb.is_empty()) {
            let n = gb.width * gb.height;
            for c in 0..3 {
                let r = l1_dssim(
                    &gb.rgb[c * n..(c + 1) * n],
                    &target[c * n..(c + 1) * n],
                    gb.width,
                    gb.height,
                    weights.lambda_dssim,
                    1.0 / 3.0,
                    &mut up.rgb[c * n..(c + 1) * n],
                )?;
                loss += r.loss / 3.0;
            }
        }
        Ok(loss)
    }

    /// Brings the optimiser state back from the backend's device when it is there (the
    /// host's `prims`, `adam` and densification statistics are current afterwards). The loop
    /// calls it before it reads or changes them; call it before reading `prims` between steps.
    pub fn sync_host(&mut self) -> Result<(), TrainError> {
        if self.resident {
            self.resident = false;
            self.backend.resident_download(&mut OptimiserState {
                prims: &mut self.prims,
                adam: &mut self.adam,
                grad_accum: &mut self.grad_accum,
                grad_count: &mut self.grad_count,
            })?;
        }
        Ok(())
    }

    /// One optimisation step on one training view; returns its loss.
    ///
    /// Thermal steps on a backend that keeps the optimiser state on its device
    /// ([`Backend::resident_step`]) run there whole: losses, backward, densification
    /// statistics and Adam. Otherwise the backend's device path ([`Backend::device_step`]) or
    /// the host path computes the gradients and Adam runs on the host.
    pub fn step(&mut self) -> Result<f64, TrainError> {
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.cfg.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ self.iteration,
        );
        let drawn = self.data.train[rng.random_range(0..self.data.train.len())];
        if self.iteration == self.cfg.warmup && self.cfg.mode.learns_beta() {
            self.sync_host()?;
            self.release_warmup_beta();
        }
        let weights = self.loss_weights();
        let has_rgb = !self.prims.sh.is_empty();
        let (vi, pair) = self.schedule(drawn, &mut rng);
        // A partner kept on the host (the last step took the host path) needs the host path.
        let host_kept = matches!(pair, Some(PairChoice::Previous(_)))
            && self.kept.as_ref().is_some_and(|k| k.gbuffers.is_some());
        let thermal_only = self.data.views[vi].thermal.is_some() && !has_rgb && !host_kept;
        if thermal_only && !self.resident {
            self.resident = self.backend.resident_upload(&mut OptimiserState {
                prims: &mut self.prims,
                adam: &mut self.adam,
                grad_accum: &mut self.grad_accum,
                grad_count: &mut self.grad_count,
            })?;
        }
        let lrs = self.lrs();
        let cam_i = self.data.views[vi].camera;
        let mut resident_loss = None;
        if let (Some(losses), true) = (
            thermal_step(&self.data, vi, pair, weights, &cam_i),
            self.resident,
        ) {
            let step = ResidentStep {
                losses,
                lrs,
                hp: AdamParams::default(),
                adam_step: self.adam.step + 1,
                min_log_scale: self.min_log_scale,
            };
            resident_loss = self.backend.resident_step(&self.prims, &step).transpose()?;
        }
        let loss = match resident_loss {
            Some(loss) => {
                self.adam.step += 1;
                self.keep(vi, pair.is_some(), None);
                loss
            }
            None => {
                self.sync_host()?;
                self.host_optimiser_step(vi, pair, &weights, &lrs, host_kept)?
            }
        };
        self.iteration += 1;

        let d = self.cfg.densify;
        // As 3DGS (15 000 of 30 000): no density changes in the second half of the run, so the
        // last primitives added have time to settle.
        if d.every > 0
            && self.iteration >= d.from
            && self.iteration < d.until.min(self.cfg.iters / 2)
            && self.iteration.is_multiple_of(d.every)
        {
            self.sync_host()?;
            self.densify(&mut rng);
        }
        let c = self.cfg.capacity;
        if (self.prims.bands > 0 || self.cfg.mode.learns_beta())
            && c.every > 0
            && self.iteration > self.cfg.warmup
            && (self.iteration - self.cfg.warmup).is_multiple_of(c.every)
        {
            self.sync_host()?;
            if self.prims.bands > 0 {
                self.drop_bands();
            }
            if self.cfg.mode.learns_beta() {
                self.freeze_gaussians();
            }
        }
        Ok(loss)
    }

    /// Gradients (the backend's device path, else render + host losses + backward),
    /// densification statistics and Adam on the host; returns the loss. `host_kept`: the
    /// partner is the host's kept copy (no device path).
    fn host_optimiser_step(
        &mut self,
        vi: usize,
        pair: Option<PairChoice>,
        weights: &LossWeights,
        lrs: &GroupLrs,
        host_kept: bool,
    ) -> Result<f64, TrainError> {
        let weights = *weights;
        let cam_i = self.data.views[vi].camera;
        let has_rgb = !self.prims.sh.is_empty();
        // The backend's device path when it has one (images stay on the device), else the
        // host path below: render, losses on the host, backward.
        let device = match (thermal_step(&self.data, vi, pair, weights, &cam_i), has_rgb) {
            (Some(step), false) if !host_kept => {
                self.backend.device_step(&self.prims, &step).transpose()?
            }
            _ => None,
        };
        let kept = self.kept.take();
        let (loss, grads) = match device {
            Some(r) => {
                self.keep(vi, pair.is_some(), None);
                (r.loss, r.grads)
            }
            None => {
                let gb_i = self.backend.render(&self.prims, &cam_i)?;
                let mut up_i = GBuffers::zeros(gb_i.width, gb_i.height, has_rgb);
                let mut loss = self.view_terms(vi, &gb_i, &weights, &mut up_i)?;

                let mut grads = None;
                if let Some(PairChoice::Previous(vj)) = pair {
                    match kept.as_ref().and_then(|k| k.gbuffers.as_ref()) {
                        Some(gb_j) => {
                            // The kept side is under stop-gradient: its upstream is dropped.
                            let cam_j = self.data.views[vj].camera;
                            let mut dropped = GBuffers::zeros(gb_j.width, gb_j.height, false);
                            let c = consistency_loss(
                                &gb_i,
                                &cam_i,
                                gb_j,
                                &cam_j,
                                &ConsistencyOptions::default(),
                                weights.lambda_consist as f32,
                                &mut up_i,
                                &mut dropped,
                            )?;
                            loss += weights.lambda_consist * c.loss;
                        }
                        // Kept on the backend's device, which this step does not use.
                        None => tracing::debug!(
                            iteration = self.iteration,
                            "consistency partner not kept on the host: term skipped"
                        ),
                    }
                }
                if let Some(PairChoice::Render(vj)) = pair {
                    let cam_j = self.data.views[vj].camera;
                    // Only the partner's G-buffers enter the loss.
                    let gb_j = self.backend.render_gbuffers(&self.prims, &cam_j)?;
                    let mut up_j = GBuffers::zeros(gb_j.width, gb_j.height, has_rgb);
                    let c = consistency_loss(
                        &gb_i,
                        &cam_i,
                        &gb_j,
                        &cam_j,
                        &ConsistencyOptions::default(),
                        weights.lambda_consist as f32,
                        &mut up_i,
                        &mut up_j,
                    )?;
                    loss += weights.lambda_consist * c.loss;
                    grads = Some(self.backend.backward(&self.prims, &cam_j, &up_j)?);
                }
                let g_i = self.backend.backward(&self.prims, &cam_i, &up_i)?;
                self.keep(vi, pair.is_some(), Some(gb_i));
                let grads = match grads {
                    None => g_i,
                    Some(mut g) => {
                        for ((_, a), (_, b)) in g.groups_mut().into_iter().zip(g_i.groups()) {
                            for (x, y) in a.iter_mut().zip(b) {
                                *x += *y;
                            }
                        }
                        g
                    }
                };
                (loss, grads)
            }
        };

        // Densification statistics: screen-space positional gradient ‖dL/dμ‖·z/f.
        for i in 0..self.prims.len() {
            let g = &grads.means[3 * i..3 * i + 3];
            let n = f64::from(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
            if n > 0.0 && n.is_finite() {
                let mu = self.prims.mean(i).map(f64::from);
                let z = cam_i.to_cam(mu)[2].abs();
                self.grad_accum[i] += n * z / cam_i.fx_px;
                self.grad_count[i] += 1;
            }
        }

        self.adam
            .step(&mut self.prims, &grads, lrs, &AdamParams::default());
        for s in &mut self.prims.log_scales {
            *s = s.max(self.min_log_scale);
        }
        Ok(loss)
    }

    /// End of the warm-up: every frozen β becomes learnable (β = 2 + 4.5e-5).
    fn release_warmup_beta(&mut self) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let mut released = 0;
        for (r, (m, v)) in self.prims.beta_raw.iter_mut().zip(
            self.adam
                .m
                .beta_raw
                .iter_mut()
                .zip(&mut self.adam.v.beta_raw),
        ) {
            if is_beta_frozen(f64::from(*r)) {
                *r = BETA_RAW_GAUSSIAN as f32;
                (*m, *v) = (0.0, 0.0);
                released += 1;
            }
        }
        tracing::debug!(
            iteration = self.iteration,
            released,
            "warm-up over: β learnable"
        );
    }

    /// Snaps primitives with β ≤ `gaussian_beta_max` and no live band to β = 2, frozen.
    fn freeze_gaussians(&mut self) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let max = self.cfg.capacity.gaussian_beta_max;
        let mut frozen = 0;
        for i in 0..self.prims.len() {
            let raw = f64::from(self.prims.beta_raw[i]);
            if !is_beta_frozen(raw) && beta_of_raw(raw).0 <= max && self.prims.live_bands(i) == 0 {
                self.prims.beta_raw[i] = BETA_RAW_FROZEN as f32;
                self.adam.m.beta_raw[i] = 0.0;
                self.adam.v.beta_raw[i] = 0.0;
                frozen += 1;
            }
        }
        self.state.capacity.gaussian_frozen_last_check = frozen;
        tracing::debug!(
            iteration = self.iteration,
            frozen,
            "β snapped to 2 (Gaussian path)"
        );
    }

    /// Clone/split/prune under the budget (see [`Densify`]).
    fn densify(&mut self, rng: &mut ChaCha8Rng) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let d = self.cfg.densify;
        let n = self.prims.len();
        let mut cand: Vec<(f64, usize)> = (0..n)
            .filter(|&i| self.grad_count[i] > 0)
            .map(|i| (self.grad_accum[i] / f64::from(self.grad_count[i]), i))
            .filter(|(g, _)| *g > d.grad_threshold)
            .collect();
        cand.sort_by(|a, b| b.0.total_cmp(&a.0));
        let room = self.cfg.budget.saturating_sub(n);
        cand.truncate(room);
        let split_scale = d.split_scale_frac * self.extent_m;
        let mut keep: Vec<usize> = Vec::with_capacity(n + cand.len());
        let mut split = vec![false; n];
        let mut new_rows: Vec<(usize, Option<[f32; 3]>)> = Vec::new();
        for &(_, i) in &cand {
            let s = self.prims.scales(i);
            if f64::from(s[0].max(s[1]).max(s[2])) > split_scale {
                split[i] = true;
                // Two samples from the primitive replace it.
                for _ in 0..2 {
                    let (rot, _, _) = crate::primitive::rotation_from_quat(self.prims.quat(i));
                    let z: [f32; 3] = [0, 1, 2].map(|a| {
                        let u: f64 = rng.random_range(-1.0..1.0);
                        (u * f64::from(s[a]) / std::f64::consts::SQRT_2) as f32
                    });
                    let off = [0, 1, 2]
                        .map(|r| rot[3 * r] * z[0] + rot[3 * r + 1] * z[1] + rot[3 * r + 2] * z[2]);
                    new_rows.push((i, Some(off)));
                }
            } else {
                new_rows.push((i, None));
            }
        }
        for (i, &was_split) in split.iter().enumerate() {
            let o = f64::from(self.prims.opacity(i).0);
            if !was_split && o >= d.prune_opacity {
                keep.push(i);
            }
        }
        let n_keep = keep.len();
        let idx: Vec<usize> = keep
            .iter()
            .copied()
            .chain(new_rows.iter().map(|r| r.0))
            .collect();
        let mut p = params::gather(&self.prims, &idx);
        let mut m = params::gather(&self.adam.m, &idx);
        let mut v = params::gather(&self.adam.v, &idx);
        let ln16 = 1.6f32.ln();
        for (k, (_, off)) in new_rows.iter().enumerate() {
            let r = n_keep + k;
            if let Some(off) = off {
                for (a, o) in off.iter().enumerate() {
                    p.means[3 * r + a] += o;
                    p.log_scales[3 * r + a] =
                        (p.log_scales[3 * r + a] - ln16).max(self.min_log_scale);
                }
            }
        }
        params::zero_rows_from(&mut m, n_keep);
        params::zero_rows_from(&mut v, n_keep);
        tracing::debug!(
            iteration = self.iteration,
            before = n,
            after = p.len(),
            densified = new_rows.len(),
            "density control"
        );
        self.prims = p;
        self.adam.m = m;
        self.adam.v = v;
        self.grad_accum = vec![0.0; self.prims.len()];
        self.grad_count = vec![0; self.prims.len()];
    }

    /// Drops negligible bands per primitive and compacts the band storage.
    fn drop_bands(&mut self) {
        // The kept G-buffers show the primitives before this change.
        self.kept = None;
        let m = self.prims.bands;
        let thr = self.cfg.capacity.band_amp_threshold as f32;
        let mut keep: Vec<Vec<usize>> = Vec::with_capacity(self.prims.len());
        let mut dropped = 0;
        for i in 0..self.prims.len() {
            let mut live: Vec<usize> = (0..self.prims.live_bands(i))
                .filter(|&j| self.prims.band_amp[m * i + j].abs() >= thr)
                .collect();
            live.sort_by(|&a, &b| {
                self.prims.band_amp[m * i + b]
                    .abs()
                    .total_cmp(&self.prims.band_amp[m * i + a].abs())
            });
            dropped += self.prims.live_bands(i) - live.len();
            keep.push(live);
        }
        let new_m = keep.iter().map(Vec::len).max().unwrap_or(0);
        let before = self.state.step_ms_sum / self.state.step_count.max(1) as f64;
        self.prims = params::compact_bands(&self.prims, &keep, new_m);
        self.adam.m = params::compact_bands(&self.adam.m, &keep, new_m);
        self.adam.v = params::compact_bands(&self.adam.v, &keep, new_m);
        let cap = &mut self.state.capacity;
        cap.bands_dropped_total = dropped;
        if new_m < m {
            cap.step_ms_before_compaction = Some(before);
            cap.step_ms_after_compaction = None;
            self.state.step_ms_sum = 0.0;
            self.state.step_count = 0;
            tracing::info!(
                iteration = self.iteration,
                from = m,
                to = new_m,
                "band storage compacted"
            );
        }
        cap.bands_now = new_m;
    }

    /// Renders the held-out views (all training views if there are none) and measures them.
    pub fn evaluate(&mut self) -> Result<EvalSummary, TrainError> {
        self.sync_host()?;
        let ids = if self.data.test.is_empty() {
            self.data.train.clone()
        } else {
            self.data.test.clone()
        };
        let mut out = Vec::new();
        for i in ids {
            let v = &self.data.views[i];
            let Some(target) = &v.thermal else { continue };
            let gb = self.backend.render(&self.prims, &v.camera)?;
            out.push(view_metrics(
                &v.name,
                &gb.thermal,
                target,
                gb.width,
                gb.height,
                self.data.range.as_ref(),
            ));
        }
        Ok(EvalSummary::from_views(out))
    }

    fn eval_row(&mut self) -> Result<MetricsRow, TrainError> {
        let e = self.evaluate()?;
        let loss = if self.state.loss_count > 0 {
            self.state.loss_sum / self.state.loss_count as f64
        } else {
            f64::NAN
        };
        self.state.loss_sum = 0.0;
        self.state.loss_count = 0;
        let row = MetricsRow {
            iteration: self.iteration,
            seconds: self.train_seconds,
            loss,
            psnr: e.psnr,
            ssim: e.ssim,
            kelvin_mae: e.kelvin_mae,
            kelvin_rmse: e.kelvin_rmse,
            primitives: self.prims.len(),
            memory_bytes: self.memory_bytes(),
        };
        report::append_row(&self.run_dir.join(files::METRICS_CSV), &row)?;
        self.state.last_eval_s = self.train_seconds;
        Ok(row)
    }

    /// Writes `checkpoint.json` atomically.
    pub fn save_checkpoint(&mut self) -> Result<(), TrainError> {
        self.sync_host()?;
        self.state.last_checkpoint_s = self.train_seconds;
        let ck = Checkpoint {
            version: CHECKPOINT_VERSION,
            iteration: self.iteration,
            train_seconds: self.train_seconds,
            primitives: (&self.prims).into(),
            adam_m: (&self.adam.m).into(),
            adam_v: (&self.adam.v).into(),
            adam_step: self.adam.step,
            state: serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null),
        };
        checkpoint::save(&self.run_dir.join(files::CHECKPOINT), &ck)?;
        Ok(())
    }

    /// Trains until `cfg.iters` or until `stop` is set (then checkpoints and returns
    /// [`Outcome::Interrupted`]). Writes the outputs when finished. A non-finite loss stops the
    /// run with [`TrainError::NonFinite`] and non-finite parameters are refused by the
    /// checkpoint writer, so a diverged run never overwrites its last good checkpoint.
    pub fn run(
        &mut self,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(&Event),
    ) -> Result<Outcome, TrainError> {
        if self.iteration == 0 && !self.run_dir.join(files::METRICS_CSV).exists() {
            let row = self.eval_row()?;
            on_event(&Event::Eval(row));
        }
        while self.iteration < self.cfg.iters {
            if stop.load(Ordering::SeqCst) {
                self.save_checkpoint()?;
                on_event(&Event::Checkpoint {
                    iteration: self.iteration,
                });
                return Ok(Outcome::Interrupted {
                    iteration: self.iteration,
                });
            }
            let t0 = Instant::now();
            let loss = self.step()?;
            if !loss.is_finite() {
                return Err(TrainError::NonFinite {
                    run_dir: self.run_dir.clone(),
                    iteration: self.iteration,
                    loss,
                });
            }
            let dt = t0.elapsed().as_secs_f64();
            self.train_seconds += dt;
            self.state.loss_sum += loss;
            self.state.loss_count += 1;
            self.state.step_ms_sum += dt * 1e3;
            self.state.step_count += 1;
            on_event(&Event::Step {
                iteration: self.iteration,
                loss,
            });
            if self.train_seconds - self.state.last_eval_s >= self.cfg.eval_every_s
                && self.iteration < self.cfg.iters
            {
                let row = self.eval_row()?;
                on_event(&Event::Eval(row));
            }
            if self.train_seconds - self.state.last_checkpoint_s >= self.cfg.checkpoint_every_s {
                self.save_checkpoint()?;
                on_event(&Event::Checkpoint {
                    iteration: self.iteration,
                });
            }
        }
        let row = self.eval_row()?;
        on_event(&Event::Eval(row));
        self.save_checkpoint()?;
        on_event(&Event::Checkpoint {
            iteration: self.iteration,
        });
        self.write_outputs()?;
        Ok(Outcome::Finished)
    }

    /// The capacity report as of now.
    pub fn capacity_report(&self) -> CapacityReport {
        let mut cap = self.state.capacity.clone();
        let m = self.prims.bands;
        cap.bands_now = m;
        cap.primitives = self.prims.len();
        cap.memory_bytes = self.memory_bytes();
        // Each band is 5 floats; ×3 with the Adam moments.
        cap.band_bytes_saved =
            (cap.bands_initial - m.min(cap.bands_initial)) * 5 * 4 * 3 * self.prims.len();
        cap.gaussian_path_primitives = (0..self.prims.len())
            .filter(|&i| {
                is_beta_frozen(f64::from(self.prims.beta_raw[i])) && self.prims.live_bands(i) == 0
            })
            .count();
        cap.band_slots_dropped = (0..self.prims.len())
            .map(|i| m - self.prims.live_bands(i))
            .sum();
        if cap.step_ms_before_compaction.is_some() && self.state.step_count > 0 {
            cap.step_ms_after_compaction =
                Some(self.state.step_ms_sum / self.state.step_count as f64);
        }
        cap
    }

    /// PLY, renders and G-buffers of the test views, β histogram, plots, eval and capacity JSON.
    pub fn write_outputs(&mut self) -> Result<(), TrainError> {
        self.sync_host()?;
        let dir = self.run_dir.clone();
        crate::ply::write_ply(&dir.join(files::PLY), &self.prims)?;
        let renders = dir.join(files::RENDERS);
        let gbuf = dir.join(files::GBUFFERS);
        std::fs::create_dir_all(&renders).map_err(io_err(&renders))?;
        std::fs::create_dir_all(&gbuf).map_err(io_err(&gbuf))?;
        for &i in &self.data.test {
            let v = &self.data.views[i];
            let gb = self.backend.render(&self.prims, &v.camera)?;
            let stem = Path::new(&v.name)
                .file_stem()
                .map_or_else(|| format!("view{i}"), |s| s.to_string_lossy().into_owned());
            if let Some(range) = &self.data.range {
                report::write_thermal_png16(
                    &renders.join(format!("{stem}.png")),
                    &gb.thermal,
                    gb.width,
                    gb.height,
                    range,
                )?;
            }
            report::write_gbuffers(&gbuf, &stem, &gb)?;
        }
        let betas: Vec<f64> = self
            .prims
            .beta_raw
            .iter()
            .map(|&r| beta_of_raw(f64::from(r)).0)
            .collect();
        report::plot_beta_histogram(&dir.join(files::BETA_HIST), &betas)?;
        let rows = report::read_rows(&dir.join(files::METRICS_CSV))?;
        report::plot_runs(
            &dir.join(files::METRICS_PNG),
            &[(self.cfg.mode.to_string(), rows)],
        )?;
        let eval = self.evaluate()?;
        write_json(&dir.join(files::EVAL), &eval)?;
        let mut cap = self.capacity_report();
        if let Some((with, general)) = self.cpu_shortcut_timing()? {
            cap.cpu_step_ms_with_shortcuts = Some(with);
            cap.cpu_step_ms_general_path = Some(general);
        }
        write_json(&dir.join(files::CAPACITY), &cap)?;
        Ok(())
    }
}

impl<B: Backend> Trainer<B> {
    /// CPU reference forward + backward of the first training view, best of 3, with the
    /// renderer's shortcuts and with every primitive forced through the general path (ms).
    fn cpu_shortcut_timing(&self) -> Result<Option<(f64, f64)>, TrainError> {
        use crate::render::{RenderSettings, prepare, render_backward_prepared, render_prepared};
        let Some(&vi) = self.data.train.first() else {
            return Ok(None);
        };
        let cam = self.data.views[vi].camera;
        let prep = prepare(&self.prims, &cam, &RenderSettings::default())?;
        let general = prep.without_shortcuts(self.prims.bands);
        let mut up = GBuffers::<f32>::zeros(prep.width, prep.height, !self.prims.sh.is_empty());
        up.thermal.fill(1.0);
        let time = |p: &crate::render::Prepared<f32>| {
            (0..3)
                .map(|_| {
                    let t0 = Instant::now();
                    let gb = render_prepared(&self.prims, p);
                    let g = render_backward_prepared(&self.prims, p, &up);
                    std::hint::black_box((gb, g));
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .fold(f64::INFINITY, f64::min)
        };
        Ok(Some((time(&prep), time(&general))))
    }
}

/// The thermal losses of a step on view `vi` (and its consistency partner `pair`) for a
/// backend's device ([`Backend::device_step`], [`Backend::resident_step`]); `None` when the view
/// has no thermal image.
fn thermal_step<'a>(
    data: &'a Dataset,
    vi: usize,
    pair: Option<PairChoice>,
    weights: LossWeights,
    cam: &'a PinholeCamera,
) -> Option<DeviceStep<'a>> {
    data.views[vi].thermal.as_ref().map(|target| DeviceStep {
        view: vi,
        cam,
        target,
        pair: pair.map(|p| {
            let cam = &data.views[p.view()].camera;
            match p {
                PairChoice::Render(_) => Partner::Render(cam),
                PairChoice::Previous(_) => Partner::Previous(cam),
            }
        }),
        weights,
        consistency: ConsistencyOptions::default(),
    })
}

fn write_json<T: Serialize>(path: &Path, v: &T) -> Result<(), TrainError> {
    let s = serde_json::to_string_pretty(v).map_err(|e| TrainError::Config {
        reason: e.to_string(),
    })?;
    std::fs::write(path, s).map_err(io_err(path))
}

fn random_unit(rng: &mut ChaCha8Rng) -> [f64; 3] {
    loop {
        let v: [f64; 3] = [0, 1, 2].map(|_| rng.random_range(-1.0..1.0));
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 0.1 && n <= 1.0 {
            return v.map(|x| x / n);
        }
    }
}

/// Mean distance to the 3 nearest neighbours (grid search over the 27 cells around each point;
/// a point with fewer neighbours there gets the mean of the others, or a scene-size default).
fn knn3_mean_distance(pts: &[[f64; 3]], lo: [f64; 3], hi: [f64; 3]) -> Vec<f64> {
    use std::collections::HashMap;
    let n = pts.len();
    if n == 0 {
        return Vec::new();
    }
    let diag = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2))
        .sqrt()
        .max(1e-6);
    let cell = (diag / (n as f64).cbrt()).max(1e-9);
    let key = |p: &[f64; 3]| [0, 1, 2].map(|a| ((p[a] - lo[a]) / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in pts.iter().enumerate() {
        grid.entry(key(p)).or_default().push(i);
    }
    let mut out = vec![f64::NAN; n];
    for (i, p) in pts.iter().enumerate() {
        let k = key(p);
        let mut best = [f64::INFINITY; 3];
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for &j in list {
                            if j == i {
                                continue;
                            }
                            let q = &pts[j];
                            let d = ((p[0] - q[0]).powi(2)
                                + (p[1] - q[1]).powi(2)
                                + (p[2] - q[2]).powi(2))
                            .sqrt();
                            if d < best[2] {
                                best[2] = d;
                                best.sort_by(f64::total_cmp);
                            }
                        }
                    }
                }
            }
        }
        let found: Vec<f64> = best
            .iter()
            .copied()
            .filter(|d| d.is_finite() && *d > 0.0)
            .collect();
        if !found.is_empty() {
            out[i] = found.iter().sum::<f64>() / found.len() as f64;
        }
    }
    let valid: Vec<f64> = out.iter().copied().filter(|d| d.is_finite()).collect();
    let fallback = if valid.is_empty() {
        cell
    } else {
        valid.iter().sum::<f64>() / valid.len() as f64
    };
    out.iter()
        .map(|d| if d.is_finite() { *d } else { fallback })
        .collect()
}

/// Overlap partner of every training view (see the module docs), and every training view's
/// overlapping views (overlap ≥ `min_overlap`, ascending index).
fn choose_pairs(
    data: &Dataset,
    centre: [f64; 3],
    min_overlap: f64,
) -> (Vec<Option<usize>>, Vec<Vec<usize>>) {
    let overlap = |a: &PinholeCamera, b: &PinholeCamera| -> f64 {
        let depth = a.to_cam(centre)[2];
        if depth.is_nan() || depth <= 0.0 {
            return 0.0;
        }
        let mut hit = 0;
        const G: usize = 6;
        for gy in 0..G {
            for gx in 0..G {
                let u = (gx as f64 + 0.5) / G as f64 * a.width as f64 - 0.5;
                let v = (gy as f64 + 0.5) / G as f64 * a.height as f64 - 0.5;
                let pc = b.to_cam(a.unproject(u, v, depth));
                if pc[2] > 0.0 {
                    let [x, y] = b.project_cam(pc);
                    if x >= 0.0
                        && y >= 0.0
                        && x <= (b.width - 1) as f64
                        && y <= (b.height - 1) as f64
                    {
                        hit += 1;
                    }
                }
            }
        }
        f64::from(hit) / (G * G) as f64
    };
    let mut pairs = vec![None; data.views.len()];
    let mut neighbours = vec![Vec::new(); data.views.len()];
    for &i in &data.train {
        let a = &data.views[i].camera;
        let ca = a.centre_world();
        let mut best: Option<(f64, usize)> = None;
        for &j in &data.train {
            if j == i {
                continue;
            }
            let b = &data.views[j].camera;
            let cb = b.centre_world();
            let baseline =
                ((ca[0] - cb[0]).powi(2) + (ca[1] - cb[1]).powi(2) + (ca[2] - cb[2]).powi(2))
                    .sqrt();
            if baseline < 1e-9 {
                continue;
            }
            let o = overlap(a, b);
            if o >= min_overlap {
                neighbours[i].push(j);
                if best.is_none_or(|(bo, _)| o > bo) {
                    best = Some((o, j));
                }
            }
        }
        pairs[i] = best.map(|b| b.1);
    }
    (pairs, neighbours)
}

/// Held-out evaluation of a finished (or checkpointed) run, as `s3tir-train eval` prints it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RunEval {
    pub run_dir: PathBuf,
    pub mode: String,
    pub psnr: f64,
    pub ssim: f64,
    /// `null` when the data are not radiometric.
    pub kelvin_mae: Option<f64>,
    pub kelvin_rmse: Option<f64>,
    pub primitives: usize,
    pub views: Vec<crate::metrics::ViewMetrics>,
}

/// Reads `RUN_DIR/config.json`.
pub fn load_config(run_dir: &Path) -> Result<TrainConfig, TrainError> {
    let path = run_dir.join(files::CONFIG);
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    serde_json::from_str(&text).map_err(|e| TrainError::Run {
        run_dir: run_dir.to_path_buf(),
        reason: format!("{}: {e}", path.display()),
    })
}

/// Evaluates the run's primitives (its PLY, or its checkpoint when there is no PLY yet) on the
/// held-out views of its dataset.
pub fn evaluate_run<B: Backend>(run_dir: &Path, backend: B) -> Result<RunEval, TrainError> {
    let cfg = load_config(run_dir)?;
    let data = Dataset::load(&cfg.data, &cfg.load)?;
    let ply = run_dir.join(files::PLY);
    let prims = if ply.exists() {
        crate::ply::read_ply(&ply)?
    } else {
        checkpoint::load(&run_dir.join(files::CHECKPOINT))?
            .primitives
            .into()
    };
    let mode = cfg.mode.to_string();
    let mut t = Trainer::bare(cfg, data, backend, run_dir);
    t.prims = prims;
    let e = t.evaluate()?;
    Ok(RunEval {
        run_dir: run_dir.to_path_buf(),
        mode,
        psnr: e.psnr,
        ssim: e.ssim,
        kelvin_mae: e.kelvin_mae,
        kelvin_rmse: e.kelvin_rmse,
        primitives: t.prims.len(),
        views: e.views,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::dataset::LoadOptions;
    use crate::dataset::synth::{self, SynthConfig};

    fn trainer(dir: &Path, partner: ConsistPartner, lambda_consist: f64) -> Trainer<CpuBackend> {
        let data_dir = dir.join("scene");
        if !data_dir.exists() {
            let scfg = SynthConfig {
                width: 32,
                height: 24,
                f_px: 27.0,
                points: 120,
                ..SynthConfig::default()
            };
            synth::write_scene(&data_dir, &scfg).unwrap();
        }
        let mut c = TrainConfig::new(data_dir.clone());
        c.iters = 100;
        c.warmup = 0;
        c.budget = 120;
        c.seed = 9;
        c.eval_every_s = 1e9;
        c.checkpoint_every_s = 1e9;
        c.densify.from = 5;
        c.densify.every = 5;
        c.capacity.every = u64::MAX;
        c.consist_partner = partner;
        c.weights.consist = lambda_consist;
        // Opaque enough from the start that views have depth (alpha ≥ 0.5) to warp by.
        c.init_opacity = 0.8;
        let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
        let run = dir.join(format!("run-{partner}-{lambda_consist}"));
        Trainer::new(c, data, CpuBackend::default(), &run).unwrap()
    }

    /// With `previous`, a step on a random view is followed by a step on its overlap partner
    /// whose term uses the first step's kept G-buffers; the schedule alternates, and density
    /// control in between drops the kept view (the next step draws a fresh one).
    #[test]
    fn previous_partner_schedule_alternates() {
        let tmp = tempfile::tempdir().unwrap();
        let mut t = trainer(tmp.path(), ConsistPartner::Previous, 0.01);
        let mut follows = 0;
        for step in 0..16u64 {
            let before = t.kept.as_ref().map(|k| (k.view, k.followed));
            t.step().unwrap();
            if t.iteration.is_multiple_of(5) {
                assert!(
                    t.kept.is_none(),
                    "step {step}: density control must drop the kept view"
                );
                continue;
            }
            let k = t.kept.as_ref().expect("the host path keeps its view");
            assert_eq!(k.iteration, step, "step {step}: kept iteration");
            assert!(
                k.gbuffers.is_some(),
                "step {step}: the CPU backend keeps its G-buffers on the host"
            );
            match before {
                Some((prev, false)) if !t.neighbours[prev].is_empty() => {
                    assert!(
                        k.followed,
                        "step {step}: must follow the lead step on view {prev}"
                    );
                    assert!(
                        t.neighbours[prev].contains(&k.view),
                        "step {step}: the follow step trains a view overlapping the lead view \
                         {prev} ({:?}), not {}",
                        t.neighbours[prev],
                        k.view
                    );
                    follows += 1;
                }
                _ => assert!(!k.followed, "step {step}: must lead (draw a fresh view)"),
            }
        }
        assert!(follows >= 4, "only {follows} follow steps in 16");
    }

    /// A follow step's loss carries λc·L_consist: the same run with λc = 0 (same schedule,
    /// the term stays on) takes the same steps and losses up to the first follow step, whose
    /// loss is larger with λc > 0.
    #[test]
    fn previous_partner_term_enters_the_loss() {
        let tmp = tempfile::tempdir().unwrap();
        let mut t = trainer(tmp.path(), ConsistPartner::Previous, 0.5);
        let mut zero = trainer(tmp.path(), ConsistPartner::Previous, 0.0);
        for step in 0..4u64 {
            let (a, b) = (t.step().unwrap(), zero.step().unwrap());
            let followed = t.kept.as_ref().is_some_and(|k| k.followed);
            if followed {
                assert!(
                    a > b + 1e-6,
                    "step {step}: follow-step loss {a} must exceed the λc = 0 run's {b}"
                );
                return;
            }
            assert_eq!(a, b, "step {step}: lead steps have no term");
        }
        panic!("no follow step in 4 steps");
    }
}
