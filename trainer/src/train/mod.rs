//! The training loop: schedule, losses, Adam, density control, capacity adaptation,
//! evaluation against wall time, checkpoints and outputs — written against [`Backend`] so the
//! Vulkan backend plugs into the same loop.
//!
//! # Schedule (paper §4.1)
//! Iterations `< warmup`: Gaussian warm-up — β frozen at exactly 2 (`beta_raw` =
//! [`BETA_RAW_FROZEN`], so the renderer takes the cheap Gaussian path) and the bands off (no
//! live slot, amplitudes 0, band lrs 0: a warm-up step costs what a 3dgs step does), only the
//! photometric loss; with a time budget the warm-up is the same fraction of the budget (see
//! `schedule`). At the warm-up's end every band slot goes live, and in modes that learn β
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
//!   and, with `cpu_timing` (`--cpu-timing`), the CPU reference renderer's step time with and
//!   without the shortcuts, measured on a training view when the outputs are written;
//! - a per-view radiometric response ([`response`]: automatic gain of 8-bit exports, drift of
//!   16-bit frames) is learned with the scene and updated after every step from the step's
//!   gradient sums; `--response auto` drops it by mid-run when the views agree.
//!
//! # Scales and aliasing
//! The renderer point-samples pixel centres, so primitives smaller than a pixel footprint can
//! fall between samples and stop receiving gradients; scales are clamped from below to half the
//! pixel footprint at the median scene depth after every step.

pub mod adam;
pub mod backend;
mod capacity;
pub mod config;
mod density;
mod error;
mod init;
mod joint;
mod outputs;
pub mod params;
pub mod response;
mod schedule;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use adam::{AdamParams, AdamState, GroupLrs, GroupSteps, Groups};
pub use backend::{
    Backend, CpuBackend, DeviceStep, DeviceStepResult, OptimiserState, Partner, ResidentStep,
    ResidentStepResult, RunShape,
};
pub use capacity::CapacityReport;
pub use config::{
    BackendKind, Capacity, ConsistPartner, DEFAULT_THERMAL_ALIGN, Densify, Joint, LOW_LIGHT_MEAN,
    Mode, RgbLoss, TrainConfig, Weights,
};
pub use density::{DensifyRound, view_space_gradient};
pub use error::TrainError;
use error::io_err;
use init::choose_pairs;
pub use joint::{Background, composite_background, composite_background_backward};
pub use outputs::{
    BackgroundFile, RunEval, evaluate_run, evaluate_run_with, load_config, read_background,
};
pub use response::{ResponseConfig, ResponseKind, ResponseModel, ResponseSummary};

use crate::camera::PinholeCamera;
use crate::checkpoint::{self, CHECKPOINT_VERSION, Checkpoint};
use crate::dataset::Dataset;
use crate::loss::align::{AlignSettings, thermal_align};
use crate::loss::consistency::{ConsistencyOptions, consistency_loss};
use crate::loss::response::{ResponseGrad, ViewResponse, view_loss_with_response};
use crate::loss::{LossWeights, view_loss};
use crate::primitive::Primitives;
use crate::render::GBuffers;
use crate::report::MetricsRow;

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
    /// Super-resolved thermal renders of the held-out thermal views (joint runs, `--sr-scale`).
    pub const RENDERS_SR: &str = "renders_sr";
    /// The same fused with the recorded held-out thermal image by back-projection
    /// ([`crate::superres`]).
    pub const RENDERS_SR_FUSED: &str = "renders_sr_fused";
    pub const GBUFFERS: &str = "gbuffers";
    /// The RGB background colour (runs with RGB views).
    pub const BACKGROUND: &str = "rgb_background.json";
}

/// What the loop reports as it goes (the CLI draws it).
#[derive(Debug, Clone)]
pub enum Event {
    Step {
        iteration: u64,
        loss: f64,
        /// Training seconds so far.
        seconds: f64,
        primitives: usize,
    },
    Eval(MetricsRow),
    Checkpoint {
        iteration: u64,
    },
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
    /// The iteration at which the warm-up ended (β released, bands and the extra terms on).
    #[serde(default)]
    warmup_ended_at: Option<u64>,
    /// Capacity checks run so far.
    #[serde(default)]
    capacity_checks: u64,
    /// The per-view responses learned with the scene (`None`: the run learns none).
    #[serde(default)]
    response: Option<ResponseModel>,
    /// `--response auto` dropped the response by mid-run: the views agreed.
    #[serde(default)]
    response_dropped: bool,
    /// The RGB views' background colour, learned with the scene (`None`: no RGB views).
    #[serde(default)]
    background: Option<joint::Background>,
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
    /// The RGB training views (the RGB pre-training draws from them).
    rgb_train: Vec<usize>,
    /// Mean value of the RGB training views (`None`: no RGB views).
    rgb_mean: Option<f64>,
    /// Each training view's partner of the other modality (joint runs), see
    /// [`Joint::pair_steps`].
    modality_partners: Vec<Option<usize>>,
    /// The held-out frames' LPIPS features, computed at the first evaluation.
    frame_features: crate::lpips::FrameFeatures,
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
        sh_k: if data.has_rgb() {
            (cfg.sh_degree.min(crate::sh::SH_MAX_DEGREE) + 1).pow(2)
        } else {
            0
        },
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
        let json = serde_json::to_string_pretty(&cfg).map_err(|source| TrainError::Json {
            path: cfg_path.clone(),
            source,
        })?;
        std::fs::write(&cfg_path, json).map_err(io_err(&cfg_path))?;
        let mut t = Self::bare(cfg, data, backend, run_dir);
        t.prims = t.initial_primitives();
        t.adam = AdamState::new(&t.prims);
        t.state.capacity = t.initial_capacity();
        t.state.response = t.initial_response();
        t.state.background = t.data.has_rgb().then(joint::Background::default);
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
            group_steps: ck.adam_group_steps,
        };
        t.iteration = ck.iteration;
        t.train_seconds = ck.train_seconds;
        // A state that does not read (a damaged or foreign checkpoint) is an error: resuming
        // with a default state would silently forget the warm-up's end, the capacity decisions
        // and the learned responses.
        let path = run_dir.join(files::CHECKPOINT);
        t.state = serde_json::from_value(ck.state)
            .map_err(|source| TrainError::CheckpointState { path, source })?;
        // Checkpoints written before the warm-up's end was recorded: an iteration-counted
        // run past it ended it at exactly `warmup`.
        if t.state.warmup_ended_at.is_none()
            && t.cfg.time_budget_s.is_none()
            && t.iteration > t.cfg.warmup
        {
            t.state.warmup_ended_at = Some(t.cfg.warmup);
        }
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
        let rgb_train = (data.train.iter().copied())
            .filter(|&i| data.views[i].rgb.is_some())
            .collect();
        let rgb_mean = joint::rgb_mean(&data);
        let modality_partners = joint::modality_partners(&data, centre);
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
            rgb_train,
            rgb_mean,
            modality_partners,
            frame_features: crate::lpips::FrameFeatures::default(),
        }
    }

    /// Bytes of parameters plus the two Adam moments (each with its copy of the band mask).
    pub fn memory_bytes(&self) -> usize {
        3 * 4 * (params::value_count(&self.prims) + self.prims.band_count.len())
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

    /// Loss and upstream gradient (into `up`) of one view's own terms, the gradient of its
    /// response (when the run learns one) and, for an RGB view, of the RGB background colour.
    fn view_terms(
        &self,
        vi: usize,
        gb: &GBuffers<f32>,
        weights: &LossWeights,
        up: &mut GBuffers<f32>,
    ) -> Result<ViewTerms, TrainError> {
        let view = &self.data.views[vi];
        let mut loss = 0.0;
        let mut response = None;
        let mut rgb_background_grad = None;
        if let Some(target) = &view.thermal {
            let mut thermal = 0.0;
            match self.view_response(vi) {
                Some(r) => {
                    let (l, g) = view_loss_with_response(gb, target, weights, &r, up)?;
                    thermal += l.total;
                    response = Some(g);
                }
                None => thermal += view_loss(gb, target, weights, up)?.total,
            }
            let wa = self.thermal_align_weight();
            if wa > 0.0 {
                let a = thermal_align(gb, target, &view.camera, &AlignSettings::default(), wa, up)?;
                thermal += a.loss;
            }
            // The modality weight scales every term of the view (one view, one modality).
            let wt = self.cfg.joint.thermal_weight;
            if wt != 1.0 {
                for (_, plane) in up.planes_mut() {
                    plane.iter_mut().for_each(|g| *g *= wt as f32);
                }
                if let Some(g) = response.as_mut() {
                    g.gain *= wt;
                    g.offset *= wt;
                }
            }
            loss += wt * thermal;
        }
        if let (Some(target), false) = (&view.rgb, gb.rgb.is_empty()) {
            let (l, g) = self.rgb_terms(gb, target, weights, up)?;
            loss += l;
            rgb_background_grad = Some(g);
        }
        Ok(ViewTerms {
            loss,
            response,
            background: rgb_background_grad,
        })
    }

    /// View `vi`'s learned response (`None`: the run learns none).
    fn view_response(&self, vi: usize) -> Option<ViewResponse> {
        self.state.response.as_ref().map(|m| m.of_view(vi))
    }

    /// The learned per-view responses (`None`: the run learns none).
    pub fn response(&self) -> Option<&ResponseModel> {
        self.state.response.as_ref()
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
        let drawn = self.draw_view(&mut rng);
        if self.state.warmup_ended_at.is_none() && self.after_warmup() {
            self.state.warmup_ended_at = Some(self.iteration);
            if self.cfg.mode.learns_beta() || self.prims.bands > 0 {
                self.sync_host()?;
            }
            if self.cfg.mode.learns_beta() {
                self.release_warmup_beta();
            }
            // Only when the warm-up switched them off (not with `warmup` 0, nor in a run
            // checkpointed before band slots were switched off during the warm-up).
            if self.prims.bands > 0 && self.prims.band_count.iter().all(|&c| c == 0) {
                self.release_warmup_bands();
            }
        }
        let weights = self.loss_weights();
        let has_rgb = !self.prims.sh.is_empty();
        let (vi, pair) = self.schedule(drawn, &mut rng);
        // A partner kept on the host (the last step took the host path) needs the host path.
        let host_kept = matches!(pair, Some(PairChoice::Previous(_)))
            && self.kept.as_ref().is_some_and(|k| k.gbuffers.is_some());
        let thermal_only = self.data.views[vi].thermal.is_some()
            && !has_rgb
            && !host_kept
            && !self.host_losses_only();
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
        let response = self.view_response(vi);
        let mut resident_loss = None;
        if let (Some(losses), true) = (
            thermal_step(&self.data, vi, pair, weights, &cam_i, response),
            self.resident && !self.host_losses_only(),
        ) {
            let hp = AdamParams::default();
            let step = ResidentStep {
                losses,
                sizes: self.adam.step_sizes(&lrs, &hp),
                hp,
                min_log_scale: self.min_log_scale,
            };
            resident_loss = self.backend.resident_step(&self.prims, &step).transpose()?;
        }
        let (loss, response_grad) = match resident_loss {
            Some(r) => {
                self.adam.advance(&lrs);
                self.keep(vi, pair.is_some(), None);
                (r.loss, r.response)
            }
            None => {
                self.sync_host()?;
                self.host_optimiser_step(vi, pair, &weights, &lrs, host_kept)?
            }
        };
        let decay = self.cfg.response.lr_final_ratio.powf(self.progress());
        if let (Some(model), Some(g)) = (self.state.response.as_mut(), response_grad) {
            model.step(&self.cfg.response, vi, g, decay);
        }
        self.decide_response();
        self.iteration += 1;

        if self.densify_due() {
            self.sync_host()?;
            self.densify(&mut rng);
        }
        if self.capacity_due() {
            self.state.capacity_checks += 1;
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
    /// densification statistics and Adam on the host; returns the loss and the gradient of
    /// the view's response. `host_kept`: the partner is the host's kept copy (no device path).
    fn host_optimiser_step(
        &mut self,
        vi: usize,
        pair: Option<PairChoice>,
        weights: &LossWeights,
        lrs: &GroupLrs,
        host_kept: bool,
    ) -> Result<(f64, Option<ResponseGrad>), TrainError> {
        let weights = *weights;
        let cam_i = self.data.views[vi].camera;
        let has_rgb = !self.prims.sh.is_empty();
        // The backend's device path when it has one (images stay on the device), else the
        // host path below: render, losses on the host, backward.
        let response = self.view_response(vi);
        let device = match (
            thermal_step(&self.data, vi, pair, weights, &cam_i, response),
            has_rgb,
        ) {
            (Some(step), false) if !host_kept && !self.host_losses_only() => {
                self.backend.device_step(&self.prims, &step).transpose()?
            }
            _ => None,
        };
        let kept = self.kept.take();
        let (loss, grads, response_grad) = match device {
            Some(r) => {
                self.keep(vi, pair.is_some(), None);
                (r.loss, r.grads, r.response)
            }
            None => {
                let gb_i = self.backend.render(&self.prims, &cam_i)?;
                let mut up_i = GBuffers::zeros(gb_i.width, gb_i.height, has_rgb);
                let terms = self.view_terms(vi, &gb_i, &weights, &mut up_i)?;
                if let (Some(bg), Some(g)) = (self.state.background.as_mut(), terms.background) {
                    bg.step(g);
                }
                let (mut loss, response_grad) = (terms.loss, terms.response);

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
                let mut grads = match grads {
                    None => g_i,
                    Some(mut g) => {
                        add_grads(&mut g, &g_i);
                        g
                    }
                };
                // Joint runs: the view of the other modality taken with this one trains in
                // the same step (one loss over both images, as the paper's end-to-end phase).
                if let Some(vr) = self.modality_partner(vi) {
                    let (l, g) = self.partner_gradients(vr, &weights)?;
                    loss += l;
                    add_grads(&mut grads, &g);
                }
                (loss, grads, response_grad)
            }
        };

        self.accumulate_densify_stats(&cam_i, &grads.means);

        self.adam
            .step(&mut self.prims, &grads, lrs, &AdamParams::default());
        for s in &mut self.prims.log_scales {
            *s = s.max(self.min_log_scale);
        }
        Ok((loss, response_grad))
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
            adam_group_steps: self.adam.group_steps,
            state: serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null),
        };
        checkpoint::save(&self.run_dir.join(files::CHECKPOINT), &ck)?;
        Ok(())
    }

    /// Trains until `cfg.iters` (or `cfg.time_budget_s` of training time; see the
    /// `schedule` module) or until `stop` is set (then checkpoints and returns
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
        while !self.finished() {
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
                seconds: self.train_seconds,
                primitives: self.prims.len(),
            });
            if self.train_seconds - self.state.last_eval_s >= self.cfg.eval_every_s
                && !self.finished()
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
}

/// What one view's own terms give ([`Trainer::view_terms`]).
struct ViewTerms {
    loss: f64,
    /// The gradient of the view's response (thermal views of a run that learns one).
    response: Option<ResponseGrad>,
    /// The gradient of the RGB background colour (RGB views).
    background: Option<[f64; 3]>,
}

/// `a += b`, group by group.
fn add_grads(a: &mut Primitives<f32>, b: &Primitives<f32>) {
    for ((_, x), (_, y)) in a.groups_mut().into_iter().zip(b.groups()) {
        for (p, q) in x.iter_mut().zip(y) {
            *p += *q;
        }
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
    response: Option<ViewResponse>,
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
        response,
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

    /// The band learning rates are 0 through the warm-up, then rise linearly to their value
    /// over `band_ramp` iterations; 0 (the default) releases them at once.
    #[test]
    fn band_learning_rates_ramp_up_after_the_warmup() {
        let tmp = tempfile::tempdir().unwrap();
        let mut t = trainer(tmp.path(), ConsistPartner::Previous, 0.01);
        assert_eq!(t.cfg.band_ramp, 0, "no ramp by default");
        t.cfg.warmup = 10;
        t.cfg.band_ramp = 10;
        assert!(t.prims.bands > 0, "s3tir mode has bands");
        let full = t.cfg.lr;
        let share = |t: &mut Trainer<CpuBackend>, it: u64| {
            t.iteration = it;
            let lr = t.lrs();
            let s = lr.band_amp / full.band_amp;
            for (what, v, f) in [
                ("freq", lr.band_freq, full.band_freq),
                ("phase", lr.band_phase, full.band_phase),
            ] {
                assert!((v / f - s).abs() < 1e-12, "{what} ramps with the amplitude");
            }
            assert_eq!(
                lr.log_scales, full.log_scales,
                "other groups are not ramped"
            );
            s
        };
        assert_eq!(share(&mut t, 9), 0.0, "bands frozen in the warm-up");
        assert!((share(&mut t, 10) - 0.1).abs() < 1e-12, "first step: 1/10");
        assert!((share(&mut t, 14) - 0.5).abs() < 1e-12, "fifth step: 1/2");
        assert_eq!(share(&mut t, 19), 1.0, "full rate after the ramp");
        assert_eq!(share(&mut t, 50), 1.0);
        t.cfg.band_ramp = 20;
        assert!((share(&mut t, 14) - 0.25).abs() < 1e-12, "a 20-step ramp");
        t.cfg.warmup = 0;
        assert_eq!(
            share(&mut t, 0),
            1.0,
            "no warm-up: bands at full rate from the start"
        );
        t.cfg.warmup = 10;
        t.cfg.band_ramp = 0;
        assert_eq!(share(&mut t, 9), 0.0);
        assert_eq!(share(&mut t, 10), 1.0, "--band-ramp 0: all at once");

        // A config written before the option ran its bands at once, and resumes so.
        t.cfg.band_ramp = 7;
        let mut v = serde_json::to_value(&t.cfg).unwrap();
        v.as_object_mut().unwrap().remove("band_ramp").unwrap();
        let old: TrainConfig = serde_json::from_value(v).unwrap();
        assert_eq!(old.band_ramp, 0);
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
