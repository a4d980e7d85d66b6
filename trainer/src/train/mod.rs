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
//! - bands only where they pay (`bands`): one pass over the training views after the
//!   warm-up, a primitive keeps its bands only when one of them has a root-mean-square
//!   amplitude gradient above `capacity.band_l1` (the residual under it has energy at a
//!   frequency the Gaussian cannot fit), the largest first, at most `capacity.band_budget` of
//!   the primitives; when none qualifies the bands are left out of the run (M = 0, said in the
//!   report's notes). Adam's proximal L1 step on the amplitudes ([`adam`]) takes the ones
//!   that stop paying to exactly zero;
//! - every `capacity.every` iterations after the grant, bands with `|ω_j| <
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
mod bands;
mod capacity;
pub mod config;
mod density;
mod error;
mod events;
pub mod files;
mod init;
mod joint;
mod outputs;
pub mod params;
pub mod response;
mod schedule;
mod step;

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
pub use bands::{BandRound, BandRoundKind, band_grant};
pub use capacity::{AlignGradient, CapacityReport, GaussianFrom};
pub use config::{
    BackendKind, Capacity, ConsistPartner, DEFAULT_RGB_PRETRAIN_FRACTION, DEFAULT_THERMAL_ALIGN,
    Densify, Joint, LOW_LIGHT_MEAN, Mode, RgbLoss, TrainConfig, Weights,
};
pub use density::{DensifyRound, view_space_gradient};
pub use error::TrainError;
use error::io_err;
pub use events::{Event, Outcome};
use init::choose_pairs;
pub use joint::{Background, composite_background, composite_background_backward};
pub use outputs::{
    BackgroundFile, RunEval, evaluate_run, evaluate_run_with, load_config, output_stem,
    read_background,
};
pub use response::{ResponseConfig, ResponseKind, ResponseModel, ResponseSummary};
use step::{KeptView, PairChoice};

use crate::camera::PinholeCamera;
use crate::checkpoint::{self, CHECKPOINT_VERSION, Checkpoint};
use crate::dataset::Dataset;
use crate::loss::align::{AlignSettings, thermal_align};
use crate::loss::consistency::{ConsistencyOptions, consistency_loss};
use crate::loss::response::{ResponseGrad, ViewResponse, view_loss_with_response};
use crate::loss::{LossWeights, view_loss};
use crate::primitive::Primitives;
use crate::render::GBuffers;

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
        t.prims = ck.primitives;
        t.adam = AdamState {
            m: ck.adam_m,
            v: ck.adam_v,
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

    /// Writes `checkpoint.json` atomically.
    pub fn save_checkpoint(&mut self) -> Result<(), TrainError> {
        self.sync_host()?;
        self.state.last_checkpoint_s = self.train_seconds;
        let ck = Checkpoint {
            version: CHECKPOINT_VERSION,
            iteration: self.iteration,
            train_seconds: self.train_seconds,
            primitives: self.prims.clone(),
            adam_m: self.adam.m.clone(),
            adam_v: self.adam.v.clone(),
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

    /// Once no primitive is off the Gaussian path (no band storage, every β frozen at 2) the
    /// consistency and smoothness terms stop — they would only pull on the opacities — and the
    /// capacity check says when; one learnable β (or one band) keeps them on.
    #[test]
    fn the_spectral_terms_stop_when_every_primitive_is_gaussian() {
        let tmp = tempfile::tempdir().unwrap();
        let mut t = trainer(tmp.path(), ConsistPartner::Render, 0.01);
        t.step().unwrap();
        assert!(t.prims.bands > 0 && t.after_warmup());
        assert!(t.consist_active(), "bands live: the term is on");
        assert!(t.loss_weights().lambda_smooth > 0.0, "β learnable: TV on");
        // No band holder left (as the grant's guard leaves the facade).
        t.keep_bands_on(&vec![false; t.prims.len()]);
        assert_eq!(t.prims.bands, 0);
        t.prims
            .beta_raw
            .fill(crate::primitive::BETA_RAW_FROZEN as f32);
        // One primitive still learning β keeps both terms.
        t.prims.beta_raw[0] = crate::primitive::BETA_RAW_GAUSSIAN as f32;
        assert!(t.consist_active() && t.loss_weights().lambda_smooth > 0.0);
        t.note_gaussian_run();
        assert!(t.state.capacity.gaussian_from.is_none());
        t.prims.beta_raw[0] = crate::primitive::BETA_RAW_FROZEN as f32;
        assert!(
            !t.consist_active(),
            "every primitive Gaussian: no consistency"
        );
        assert_eq!(t.loss_weights().lambda_smooth, 0.0, "and no smoothness");
        assert_eq!(t.schedule(3, &mut ChaCha8Rng::seed_from_u64(1)), (3, None));
        t.note_gaussian_run();
        let at = t.state.capacity.gaussian_from.expect("the check says when");
        assert_eq!(at.iteration, t.iteration);
        assert!(
            t.state
                .capacity
                .notes
                .iter()
                .any(|n| n.contains("Gaussian path")),
            "{:?}",
            t.state.capacity.notes
        );
        // 3dgs mode never had the terms: nothing to say.
        let mut g = trainer(tmp.path(), ConsistPartner::Render, 0.02);
        g.cfg.mode = Mode::Gaussian;
        g.note_gaussian_run();
        assert!(g.state.capacity.gaussian_from.is_none());
    }

    /// The alignment loss's share of the position gradient is sampled on thermal host steps
    /// while the loss is on, and is its own: at the same state, ten times the weight gives
    /// exactly ten times the ratio (the other terms' gradient does not contain it); off, no
    /// sample.
    #[test]
    fn the_alignment_losss_share_of_the_gradient_is_measured() {
        let tmp = tempfile::tempdir().unwrap();
        let first_ratio = |weight: f64| {
            let mut t = trainer(tmp.path(), ConsistPartner::Render, 0.01);
            t.cfg.joint.thermal_align = Some(weight);
            assert!(t.align_share_due(t.data.train[0]) == (weight > 0.0));
            t.step().unwrap();
            t.capacity_report()
                .align_gradient
                .map(|a| (a.ratios[0], a.samples, a.median))
        };
        let (weak, n, median) = first_ratio(5.0).expect("a sample at iteration 0");
        assert_eq!((n, median), (1, Some(weak)), "summarised in the report");
        let (strong, _, _) = first_ratio(50.0).expect("a sample at iteration 0");
        assert!(
            weak > 0.05 && (strong / weak - 10.0).abs() < 0.01,
            "ratios {weak} at weight 5 and {strong} at weight 50: expected a real pull, ×10"
        );
        assert_eq!(first_ratio(0.0), None, "the loss off: nothing sampled");
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
