//! `s3tir-train bench`: training steps per second of the Vulkan backend against the CPU
//! backend on the same scene, budget and loop, the cost of the full S³-TIR primitive against the
//! 3DGS mode, the CPU backend on every core against one thread, a joint RGB + thermal run (the
//! same scene with every second view RGB, SH degree 0) against the thermal-only run, and where
//! the GPU time goes (timestamp queries per kernel). Every figure is a ratio between runs made
//! in the same invocation, on this machine.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::backend::VulkanBackend;
use super::context::ContextOptions;
use super::error::GpuError;
use crate::dataset::synth::{self, SynthConfig};
use crate::dataset::{Dataset, DatasetError, LoadOptions};
use crate::render::RenderSettings;
use crate::train::{Backend, ConsistPartner, CpuBackend, Mode, TrainConfig, TrainError, Trainer};

/// What to measure.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    pub width: usize,
    pub height: usize,
    pub views: usize,
    /// Primitives (initialised from as many sparse points; densification off, so constant).
    pub primitives: usize,
    /// Timed steps per configuration (in rounds of at most 5 per configuration, interleaved).
    pub steps: usize,
    /// Untimed steps before timing (pipeline compilation, buffer growth).
    pub warmup_steps: usize,
    /// Configurations with bands: the fraction of the primitives that hold them, spread evenly
    /// over the set (the others band-free, as the band grant leaves them); 1: every primitive.
    pub band_holders: f64,
    pub device: ContextOptions,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            width: 96,
            height: 72,
            views: 12,
            primitives: 2_000,
            steps: 20,
            warmup_steps: 3,
            band_holders: 1.0,
            device: ContextOptions::default(),
        }
    }
}

/// GPU time of one kernel per training step, in both modes.
#[derive(Debug, Clone, Serialize)]
pub struct KernelShare {
    pub kernel: String,
    /// s3tir mode.
    pub ms_per_step: f64,
    /// Fraction of all kernels' GPU time, s3tir mode.
    pub share: f64,
    /// 3dgs mode (0 when the kernel does not run in that mode).
    pub gaussian_ms_per_step: f64,
    /// Dispatches per step, s3tir mode and 3dgs mode. On lavapipe every dispatch costs a fixed
    /// ~0.05–0.1 ms (its worker threads wake, run and join) however little work it holds.
    pub dispatches_per_step: f64,
    pub gaussian_dispatches_per_step: f64,
}

/// The benchmark's figures (`--json` prints this object).
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    pub device: String,
    pub width: usize,
    pub height: usize,
    pub primitives: usize,
    pub steps: usize,
    /// Primitives holding bands in the configurations with bands (1: all).
    pub band_holders: f64,
    /// CPU backend, s3tir mode, on every core (rayon's pool: `cpu_threads`).
    pub cpu_steps_per_s: f64,
    /// Threads of the CPU backend's pool.
    pub cpu_threads: usize,
    /// CPU backend, s3tir mode, on one thread (the same steps: the results are the same bits).
    pub cpu_one_thread_steps_per_s: f64,
    /// `cpu_steps_per_s / cpu_one_thread_steps_per_s`: what the extra cores buy the CPU backend.
    pub cpu_parallel_speedup: f64,
    /// Vulkan backend, s3tir mode (= `s3tir_steps_per_s`).
    pub vulkan_steps_per_s: f64,
    /// Vulkan backend, s3tir mode (learnable β, M bands, every term of eq. 6; the consistency
    /// partner is the previous step's view, the default).
    pub s3tir_steps_per_s: f64,
    /// Vulkan backend, 3dgs mode (β ≡ 2, no bands).
    pub gaussian_steps_per_s: f64,
    /// Process CPU time (every thread: lavapipe's workers included) per step, CPU backend.
    /// Unlike steps/s, this hardly changes when other work loads the machine, so it compares
    /// the backends' efficiency on a shared machine; on a GPU the Vulkan figure is host work only.
    pub cpu_backend_cpu_ms_per_step: f64,
    /// Process CPU time per step, Vulkan backend, s3tir mode.
    pub vulkan_cpu_ms_per_step: f64,
    /// Process CPU time per step, Vulkan backend, 3dgs mode.
    pub gaussian_cpu_ms_per_step: f64,
    /// `vulkan_steps_per_s / cpu_steps_per_s` (goal ≥ 3).
    pub vulkan_speedup_over_cpu: f64,
    /// `gaussian_steps_per_s / s3tir_steps_per_s`: cost of the full primitive (goal ≤ 1.5).
    pub s3tir_cost_over_gaussian: f64,
    /// Vulkan backend, s3tir mode with the consistency partner rendered in every step
    /// (`--consist-partner render`: a second view's projection, sort, forward and backward).
    pub s3tir_render_partner_steps_per_s: f64,
    /// `gaussian_steps_per_s / s3tir_render_partner_steps_per_s`.
    pub s3tir_render_partner_cost_over_gaussian: f64,
    /// Per-kernel GPU time in s3tir and 3dgs mode, largest (in s3tir mode) first.
    pub kernels: Vec<KernelShare>,
    pub peak_gpu_bytes: u64,
    /// Vulkan s3tir steps: host reads of GPU data per step (each waits for the GPU), their
    /// bytes, and command submissions per step.
    pub host_reads_per_step: f64,
    pub host_read_bytes_per_step: f64,
    pub submissions_per_step: f64,
    /// Vulkan backend, s3tir mode, the joint RGB + thermal scene (the bench scene with every
    /// second view's image RGB at the same size; SH degree 0). Its steps take the host path:
    /// render and backward on the GPU, the losses (RGB L1 + D-SSIM, thermal terms and the
    /// thermal alignment term) and Adam on the host.
    pub joint_steps_per_s: f64,
    /// `s3tir_steps_per_s / joint_steps_per_s`: the time of a joint step over a thermal-only
    /// step's (goal ≤ 1.6). A joint step trains two images (pair steps: the drawn view and
    /// the other camera's image of its instant).
    pub joint_over_thermal: f64,
    /// The joint run with one image per step (`--no-pair-steps`): a thermal or an RGB view.
    pub joint_single_steps_per_s: f64,
    /// `s3tir_steps_per_s / joint_single_steps_per_s`.
    pub joint_single_over_thermal: f64,
    /// Vulkan backend, s3tir mode, the thermal-only scene on the host path (device losses off):
    /// the joint steps' path without the colour or RGB views.
    pub thermal_host_path_steps_per_s: f64,
    /// GPU time of every kernel per step, thermal-only run (s3tir mode) and joint run (from the
    /// per-kernel timestamps).
    pub thermal_kernel_ms_per_step: f64,
    pub joint_kernel_ms_per_step: f64,
    /// The colour kernels' (`*_rgb`) share of `joint_kernel_ms_per_step`.
    pub joint_colour_kernel_ms_per_step: f64,
    /// A joint step's wall time not spent in kernels: the host's work (losses, Adam, reading
    /// the images back and uploading their gradients, recording and submitting).
    pub joint_host_ms_per_step: f64,
}

impl BenchReport {
    /// The joint run's figures in one line of text (`s3tir-train bench` prints it).
    pub fn joint_line(&self) -> String {
        format!(
            "joint RGB + thermal (half the views RGB, SH degree 0): {:.2} steps/s, {:.2}x the \
             thermal step (goal <= 1.6; a joint step trains two images, a view and the other \
             camera's image of its instant: {:.2}x per image; with one image per step, \
             --no-pair-steps: {:.2} steps/s, {:.2}x); per joint step {:.1} ms in \
             kernels ({:.1} ms of them colour kernels) and {:.1} ms on the host (losses, Adam, \
             image reads: the host path); thermal-only step {:.1} ms in kernels, {:.2} steps/s \
             on the host path",
            self.joint_steps_per_s,
            self.joint_over_thermal,
            self.joint_over_thermal / 2.0,
            self.joint_single_steps_per_s,
            self.joint_single_over_thermal,
            self.joint_kernel_ms_per_step,
            self.joint_colour_kernel_ms_per_step,
            self.joint_host_ms_per_step,
            self.thermal_kernel_ms_per_step,
            self.thermal_host_path_steps_per_s,
        )
    }
}

/// Errors of the benchmark.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("benchmark scene in {path}")]
    Scene {
        path: PathBuf,
        #[source]
        source: DatasetError,
    },
    #[error("benchmark training run")]
    Train {
        #[source]
        source: TrainError,
    },
    #[error("benchmark Vulkan backend")]
    Gpu {
        #[source]
        source: GpuError,
    },
    #[error("benchmark: {what} needs at least 1, got 0")]
    Zero { what: &'static str },
    #[error("benchmark: a one-thread pool for the CPU backend")]
    ThreadPool {
        #[source]
        source: rayon::ThreadPoolBuildError,
    },
}

fn config(data: &Path, mode: Mode, partner: ConsistPartner, opts: &BenchOptions) -> TrainConfig {
    let mut c = TrainConfig::new(data.to_path_buf());
    c.mode = mode;
    c.consist_partner = partner;
    c.iters = (opts.steps + opts.warmup_steps) as u64 + 1;
    c.warmup = 0; // spectral modulation and shape on from the first step
    c.budget = opts.primitives;
    c.seed = 1;
    c.eval_every_s = 1e12;
    c.checkpoint_every_s = 1e12;
    c.densify.from = u64::MAX; // constant primitive count
    c.capacity.every = u64::MAX;
    c
}

/// The images the benchmark scene trains on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scene {
    /// The synthetic thermal scene.
    Thermal,
    /// The same scene with every second view's image an RGB image of the same size (three
    /// planes made from its thermal image): a joint RGB + thermal run, with colour.
    Joint,
    /// The joint scene trained one image per step (`--no-pair-steps`).
    JointSingle,
}

/// Turns every second view of `data` into an RGB view (see [`Scene::Joint`]).
fn make_joint(data: &mut Dataset) {
    for view in data.views.iter_mut().skip(1).step_by(2) {
        if let Some(t) = view.thermal.take() {
            let rgb: Vec<f32> = (t.iter().copied())
                .chain(t.iter().map(|x| 1.0 - x))
                .chain(t.iter().map(|x| 0.25 + 0.5 * x))
                .collect();
            view.rgb = Some(rgb);
        }
    }
}

/// `n` flags, `fraction` of them true, spread evenly (flag `i` is true when `⌊(i+1)·fraction⌋`
/// exceeds `⌊i·fraction⌋`).
fn evenly_spread(n: usize, fraction: f64) -> Vec<bool> {
    let f = fraction.clamp(0.0, 1.0);
    (0..n)
        .map(|i| ((i + 1) as f64 * f).floor() > (i as f64 * f).floor())
        .collect()
}

/// CPU time consumed so far by every thread of this process, in seconds.
fn process_cpu_s() -> f64 {
    use nix::time::{ClockId, clock_gettime};
    clock_gettime(ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(f64::NAN)
}

/// What a [`Timed`] configuration measured.
struct Measured {
    steps_per_s: f64,
    cpu_ms_per_step: f64,
    /// Vulkan traffic during the timed steps: (host reads, bytes read, submissions).
    traffic: (u64, u64, u64),
}

/// One benchmark configuration: a training run on `backend` in `mode`, warmed up, timed in
/// rounds ([`Timed::round`]) that [`run_in`] interleaves with the other configurations'.
struct Timed<B: Backend> {
    trainer: Trainer<B>,
    steps: usize,
    seconds: f64,
    cpu_s: f64,
    traffic_start: (u64, u64, u64),
}

impl<B: Backend> Timed<B> {
    /// Loads the scene, builds the trainer and runs the untimed warm-up steps; `before_timing`
    /// runs once after them, and `traffic` reads the backend's traffic counters.
    fn start(
        data_dir: &Path,
        run_dir: &Path,
        (mode, partner, scene): (Mode, ConsistPartner, Scene),
        opts: &BenchOptions,
        backend: B,
        before_timing: &mut dyn FnMut(&mut B),
        traffic: &dyn Fn(&B) -> (u64, u64, u64),
    ) -> Result<Self, BenchError> {
        let train = |source| BenchError::Train { source };
        let mut data = Dataset::load(data_dir, &LoadOptions::default()).map_err(|source| {
            BenchError::Scene {
                path: data_dir.to_path_buf(),
                source,
            }
        })?;
        let mut cfg = config(data_dir, mode, partner, opts);
        if scene != Scene::Thermal {
            make_joint(&mut data);
            cfg.joint.pair_steps = scene == Scene::Joint;
        }
        let mut trainer = Trainer::new(cfg, data, backend, run_dir).map_err(train)?;
        if trainer.prims.bands > 0 && opts.band_holders < 1.0 {
            let keep = evenly_spread(trainer.prims.len(), opts.band_holders);
            trainer.keep_bands_on(&keep);
        }
        for _ in 0..opts.warmup_steps {
            trainer.step().map_err(train)?;
        }
        before_timing(&mut trainer.backend);
        let traffic_start = traffic(&trainer.backend);
        Ok(Self {
            trainer,
            steps: 0,
            seconds: 0.0,
            cpu_s: 0.0,
            traffic_start,
        })
    }

    /// Times `steps` more training steps (wall clock and process CPU time).
    fn round(&mut self, steps: usize) -> Result<(), BenchError> {
        let start = Instant::now();
        let cpu_start = process_cpu_s();
        for _ in 0..steps {
            self.trainer
                .step()
                .map_err(|source| BenchError::Train { source })?;
        }
        self.cpu_s += process_cpu_s() - cpu_start;
        self.seconds += start.elapsed().as_secs_f64();
        self.steps += steps;
        Ok(())
    }

    /// The figures, and the backend back (its memory and timings).
    fn finish(
        mut self,
        traffic: &dyn Fn(&B) -> (u64, u64, u64),
    ) -> Result<(Measured, B), BenchError> {
        let end = traffic(&self.trainer.backend);
        self.trainer
            .sync_host()
            .map_err(|source| BenchError::Train { source })?;
        let steps = self.steps.max(1) as f64;
        let measured = Measured {
            steps_per_s: self.steps as f64 / self.seconds.max(1e-9),
            cpu_ms_per_step: 1e3 * self.cpu_s / steps,
            traffic: (
                end.0 - self.traffic_start.0,
                end.1 - self.traffic_start.1,
                end.2 - self.traffic_start.2,
            ),
        };
        Ok((measured, self.trainer.backend))
    }
}

/// The timed steps split into rounds of at most this many steps per configuration.
const ROUND_STEPS: usize = 5;

/// Runs the benchmark; `progress` gets one line per stage.
pub fn run(opts: &BenchOptions, progress: &mut dyn FnMut(&str)) -> Result<BenchReport, BenchError> {
    if opts.steps == 0 {
        return Err(BenchError::Zero { what: "--steps" });
    }
    if opts.primitives == 0 {
        return Err(BenchError::Zero {
            what: "--primitives",
        });
    }
    let root = std::env::temp_dir().join(format!("s3tir-bench-{}", std::process::id()));
    let result = run_in(&root, opts, progress);
    let _ = std::fs::remove_dir_all(&root);
    result
}

/// The Vulkan configurations timed side by side (see [`VULKAN_RUNS`]).
#[derive(Debug, Clone, Copy)]
enum Vk {
    Gaussian,
    S3tir,
    RenderedPartner,
    Joint,
    JointSingle,
    HostPath,
}

/// One Vulkan configuration: what it is, its run folder, and how it trains.
struct VulkanRun {
    which: Vk,
    label: &'static str,
    dir: &'static str,
    mode: Mode,
    partner: ConsistPartner,
    scene: Scene,
    /// Losses on the device (false: the host path, as joint steps take).
    device_losses: bool,
}

/// Every Vulkan configuration, in the order of [`Vk`] (index = `Vk as usize`).
const VULKAN_RUNS: [VulkanRun; 6] = [
    VulkanRun {
        which: Vk::Gaussian,
        label: "3dgs mode",
        dir: "vk-3dgs",
        mode: Mode::Gaussian,
        partner: ConsistPartner::Previous,
        scene: Scene::Thermal,
        device_losses: true,
    },
    VulkanRun {
        which: Vk::S3tir,
        label: "s3tir mode",
        dir: "vk-s3tir",
        mode: Mode::S3tir,
        partner: ConsistPartner::Previous,
        scene: Scene::Thermal,
        device_losses: true,
    },
    VulkanRun {
        which: Vk::RenderedPartner,
        label: "s3tir mode, consistency partner rendered each step",
        dir: "vk-s3tir-render",
        mode: Mode::S3tir,
        partner: ConsistPartner::Render,
        scene: Scene::Thermal,
        device_losses: true,
    },
    VulkanRun {
        which: Vk::Joint,
        label: "s3tir mode, joint RGB + thermal scene",
        dir: "vk-joint",
        mode: Mode::S3tir,
        partner: ConsistPartner::Previous,
        scene: Scene::Joint,
        device_losses: true,
    },
    VulkanRun {
        which: Vk::JointSingle,
        label: "s3tir mode, joint scene, one image per step",
        dir: "vk-joint-single",
        mode: Mode::S3tir,
        partner: ConsistPartner::Previous,
        scene: Scene::JointSingle,
        device_losses: true,
    },
    VulkanRun {
        which: Vk::HostPath,
        label: "s3tir mode, host path (device losses off)",
        dir: "vk-host",
        mode: Mode::S3tir,
        partner: ConsistPartner::Previous,
        scene: Scene::Thermal,
        device_losses: false,
    },
];

/// What the timed configurations measured: the CPU backend on every core and on one thread,
/// and every Vulkan configuration (indexed by [`Vk`]).
struct Timings {
    cpu: Measured,
    cpu_one_thread: Measured,
    vulkan: Vec<Measured>,
    /// The Vulkan device's name.
    device: String,
}

impl Timings {
    fn vk(&self, which: Vk) -> &Measured {
        &self.vulkan[which as usize]
    }
}

/// The per-kernel GPU times of the profiled runs.
struct Profiles {
    s3tir: KernelTimes,
    gaussian: KernelTimes,
    joint: KernelTimes,
    /// Peak device memory of the s3tir run.
    peak_gpu_bytes: u64,
}

fn run_in(
    root: &Path,
    opts: &BenchOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<BenchReport, BenchError> {
    let data_dir = root.join("scene");
    let scene = SynthConfig::bench(opts.width, opts.height, opts.views, opts.primitives);
    progress(&format!(
        "scene: {} views of {}x{}, {} primitives",
        opts.views, opts.width, opts.height, opts.primitives
    ));
    synth::write_scene(&data_dir, &scene).map_err(|source| BenchError::Scene {
        path: data_dir.clone(),
        source,
    })?;
    let settings = RenderSettings::default();
    let timings = time_steps(&data_dir, root, opts, settings, progress)?;
    // Timestamps add work of their own: time the kernels in separate passes (the timed runs'
    // backends are dropped by now).
    let profiles = profile_kernels(&data_dir, root, opts, settings, progress)?;
    Ok(report(opts, &timings, profiles))
}

fn vulkan_traffic(b: &VulkanBackend) -> (u64, u64, u64) {
    b.context().traffic()
}

fn no_traffic(_: &CpuBackend) -> (u64, u64, u64) {
    (0, 0, 0)
}

/// Warms every configuration up, then times them in interleaved rounds, so a slow spell of the
/// machine (other tenants, frequency changes) falls on all of them alike and the ratios stay
/// fair.
fn time_steps(
    data_dir: &Path,
    root: &Path,
    opts: &BenchOptions,
    settings: RenderSettings,
    progress: &mut dyn FnMut(&str),
) -> Result<Timings, BenchError> {
    let thermal = (Mode::S3tir, ConsistPartner::Previous, Scene::Thermal);
    progress("CPU backend, s3tir mode: warm-up");
    let cpu_run = |dir: &str| {
        Timed::start(
            data_dir,
            &root.join(dir),
            thermal,
            opts,
            CpuBackend { settings },
            &mut |_| {},
            &no_traffic,
        )
    };
    let mut cpu = cpu_run("cpu")?;
    // The CPU backend once more, its rayon work on one thread: the parallel speed-up.
    progress("CPU backend, s3tir mode, one thread: warm-up");
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|source| BenchError::ThreadPool { source })?;
    let mut cpu1 = one_thread.install(|| cpu_run("cpu-1"))?;
    let mut vulkan = Vec::with_capacity(VULKAN_RUNS.len());
    for (k, run) in VULKAN_RUNS.iter().enumerate() {
        debug_assert_eq!(run.which as usize, k, "VULKAN_RUNS is in the order of Vk");
        progress(&format!("Vulkan backend, {}: warm-up", run.label));
        let mut vk = VulkanBackend::new(&opts.device, settings)
            .map_err(|source| BenchError::Gpu { source })?;
        vk.set_device_losses(run.device_losses);
        vulkan.push(Timed::start(
            data_dir,
            &root.join(run.dir),
            (run.mode, run.partner, run.scene),
            opts,
            vk,
            &mut |_| {},
            &vulkan_traffic,
        )?);
    }
    let rounds = opts.steps.div_ceil(ROUND_STEPS);
    let mut left = opts.steps;
    for r in 0..rounds {
        let n = left.div_ceil(rounds - r);
        left -= n;
        progress(&format!(
            "round {}/{rounds}: {n} steps of each configuration",
            r + 1
        ));
        cpu.round(n)?;
        one_thread.install(|| cpu1.round(n))?;
        for timed in &mut vulkan {
            timed.round(n)?;
        }
    }
    let mut device = String::new();
    let mut measured = Vec::with_capacity(vulkan.len());
    for (k, timed) in vulkan.into_iter().enumerate() {
        let (m, backend) = timed.finish(&vulkan_traffic)?;
        if k == Vk::S3tir as usize {
            device.clone_from(&backend.context().report().name);
        }
        measured.push(m);
        // The backend (its device memory) goes here, before the profiled runs.
    }
    Ok(Timings {
        cpu: cpu.finish(&no_traffic)?.0,
        cpu_one_thread: cpu1.finish(&no_traffic)?.0,
        vulkan: measured,
        device,
    })
}

/// GPU time per kernel in s3tir mode, 3dgs mode and the joint scene, each its own run.
fn profile_kernels(
    data_dir: &Path,
    root: &Path,
    opts: &BenchOptions,
    settings: RenderSettings,
    progress: &mut dyn FnMut(&str),
) -> Result<Profiles, BenchError> {
    let mut run = |mode, scene| profile(data_dir, root, (mode, scene), opts, settings, progress);
    let (s3tir, vk) = run(Mode::S3tir, Scene::Thermal)?;
    let peak_gpu_bytes = vk.context().peak_allocated_bytes();
    drop(vk);
    let (gaussian, _) = run(Mode::Gaussian, Scene::Thermal)?;
    let (joint, _) = run(Mode::S3tir, Scene::Joint)?;
    Ok(Profiles {
        s3tir,
        gaussian,
        joint,
        peak_gpu_bytes,
    })
}

/// Each kernel's GPU time per step in both modes, largest (in s3tir mode) first.
fn kernel_shares(s3tir: &KernelTimes, gaussian: &KernelTimes, steps: f64) -> Vec<KernelShare> {
    let total_ns: f64 = s3tir.values().map(|k| k.0).sum();
    let mut kernels: Vec<KernelShare> = s3tir
        .iter()
        .map(|(kernel, &(ns, count))| {
            let (g_ns, g_count) = gaussian.get(kernel).copied().unwrap_or((0.0, 0));
            KernelShare {
                kernel: kernel.clone(),
                ms_per_step: ns / 1e6 / steps,
                share: if total_ns > 0.0 { ns / total_ns } else { 0.0 },
                gaussian_ms_per_step: g_ns / 1e6 / steps,
                dispatches_per_step: count as f64 / steps,
                gaussian_dispatches_per_step: g_count as f64 / steps,
            }
        })
        .collect();
    kernels.extend(
        gaussian
            .iter()
            .filter(|(k, _)| !s3tir.contains_key(*k))
            .map(|(kernel, &(ns, count))| KernelShare {
                kernel: kernel.clone(),
                ms_per_step: 0.0,
                share: 0.0,
                gaussian_ms_per_step: ns / 1e6 / steps,
                dispatches_per_step: 0.0,
                gaussian_dispatches_per_step: count as f64 / steps,
            }),
    );
    kernels.sort_by(|a, b| b.ms_per_step.total_cmp(&a.ms_per_step));
    kernels
}

/// The figures, as ratios between the configurations.
fn report(opts: &BenchOptions, t: &Timings, p: Profiles) -> BenchReport {
    let steps = opts.steps as f64;
    let kernel_ms = |k: &KernelTimes, colour_only: bool| {
        k.iter()
            .filter(|(name, _)| !colour_only || name.ends_with("_rgb"))
            .map(|(_, t)| t.0)
            .sum::<f64>()
            / 1e6
            / steps
    };
    let sps = |which: Vk| t.vk(which).steps_per_s;
    let s3tir = t.vk(Vk::S3tir);
    let per_step = |x: u64| x as f64 / steps;
    let joint_kernel_ms = kernel_ms(&p.joint, false);
    BenchReport {
        device: t.device.clone(),
        width: opts.width,
        height: opts.height,
        primitives: opts.primitives,
        steps: opts.steps,
        band_holders: opts.band_holders,
        cpu_steps_per_s: t.cpu.steps_per_s,
        cpu_threads: rayon::current_num_threads(),
        cpu_one_thread_steps_per_s: t.cpu_one_thread.steps_per_s,
        cpu_parallel_speedup: t.cpu.steps_per_s / t.cpu_one_thread.steps_per_s,
        vulkan_steps_per_s: s3tir.steps_per_s,
        s3tir_steps_per_s: s3tir.steps_per_s,
        gaussian_steps_per_s: sps(Vk::Gaussian),
        vulkan_speedup_over_cpu: s3tir.steps_per_s / t.cpu.steps_per_s,
        s3tir_cost_over_gaussian: sps(Vk::Gaussian) / s3tir.steps_per_s,
        s3tir_render_partner_steps_per_s: sps(Vk::RenderedPartner),
        s3tir_render_partner_cost_over_gaussian: sps(Vk::Gaussian) / sps(Vk::RenderedPartner),
        cpu_backend_cpu_ms_per_step: t.cpu.cpu_ms_per_step,
        vulkan_cpu_ms_per_step: s3tir.cpu_ms_per_step,
        gaussian_cpu_ms_per_step: t.vk(Vk::Gaussian).cpu_ms_per_step,
        kernels: kernel_shares(&p.s3tir, &p.gaussian, steps),
        peak_gpu_bytes: p.peak_gpu_bytes,
        host_reads_per_step: per_step(s3tir.traffic.0),
        host_read_bytes_per_step: per_step(s3tir.traffic.1),
        submissions_per_step: per_step(s3tir.traffic.2),
        joint_steps_per_s: sps(Vk::Joint),
        joint_over_thermal: s3tir.steps_per_s / sps(Vk::Joint),
        joint_single_steps_per_s: sps(Vk::JointSingle),
        joint_single_over_thermal: s3tir.steps_per_s / sps(Vk::JointSingle),
        thermal_host_path_steps_per_s: sps(Vk::HostPath),
        thermal_kernel_ms_per_step: kernel_ms(&p.s3tir, false),
        joint_kernel_ms_per_step: joint_kernel_ms,
        joint_colour_kernel_ms_per_step: kernel_ms(&p.joint, true),
        joint_host_ms_per_step: (1e3 / sps(Vk::Joint) - joint_kernel_ms).max(0.0),
    }
}

/// Per kernel name: GPU time (ns) and dispatches.
type KernelTimes = BTreeMap<String, (f64, u64)>;

/// GPU time per kernel (ns) and its dispatches, summed over `opts.steps` steps of a Vulkan run
/// in `mode` on `scene`, timed with timestamp queries; returns the backend too (its peak memory
/// is reported).
fn profile(
    data_dir: &Path,
    root: &Path,
    (mode, scene): (Mode, Scene),
    opts: &BenchOptions,
    settings: RenderSettings,
    progress: &mut dyn FnMut(&str),
) -> Result<(KernelTimes, VulkanBackend), BenchError> {
    let name = match scene {
        Scene::Thermal => mode.to_string(),
        Scene::Joint => format!("{mode}-joint"),
        Scene::JointSingle => format!("{mode}-joint-single"),
    };
    progress(&format!(
        "Vulkan backend, {name} mode: per-kernel timestamps"
    ));
    let vk =
        VulkanBackend::new(&opts.device, settings).map_err(|source| BenchError::Gpu { source })?;
    let mut profiled = Timed::start(
        data_dir,
        &root.join(format!("vk-prof-{name}")),
        (mode, ConsistPartner::Previous, scene),
        opts,
        vk,
        &mut |b: &mut VulkanBackend| {
            b.set_profiling(true);
            let _ = b.take_timings();
        },
        &vulkan_traffic,
    )?;
    profiled.round(opts.steps)?;
    let (_, vk) = profiled.finish(&vulkan_traffic)?;
    let mut per_kernel = KernelTimes::new();
    for t in vk.take_timings() {
        let k = per_kernel.entry(t.kernel).or_default();
        k.0 += t.duration_ns;
        k.1 += 1;
    }
    Ok((per_kernel, vk))
}
