//! Proves the RGB (SH colour) branch of the Vulkan rasteriser matches the CPU reference on
//! lavapipe: the R, G, B planes of the forward pass, the gradients of every parameter group
//! (the SH coefficients and the means through the view direction included) for upstream
//! gradients on every plane, with float atomics and with the compare-and-swap fallback, with and
//! without subgroup sums; that a scene without colour runs the thermal kernels only and renders
//! the same bits as with colour; that the backend's device paths refuse colour; and that a few
//! joint RGB + thermal training steps on the Vulkan backend follow the CPU backend's losses.
//!
//! Bounds (stated, with what was measured on lavapipe, Mesa 22.3):
//!   - forward, R, G, B planes against the CPU reference in f32 and in f64 (SH degrees 0, 1,
//!     3): max |Δ| ≤ 1e-4 at every pixel where the GPU takes the CPU's samples (its alpha
//!     within 1e-5 of the CPU's), and ≥ 99.9 % of all values within 1e-4 (room for the f32
//!     threshold flips of `gpu_raster.rs`, which move every plane alike; none seen in these
//!     scenes). Measured: max |Δ| 2.6e-6 against f32, 4.7e-6 against f64, every pixel;
//!   - backward, relative L2 error ‖g_gpu − g_ref‖ / ‖g_ref‖ per group against the CPU
//!     reference (f32 and f64), every group (SH coefficients and means included) ≤ 1e-4, for
//!     float atomics and the compare-and-swap fallback, with and without subgroup sums.
//!     Measured: SH 1.4e-6, means 1.1e-5, quaternions 1.3e-5, the rest ≤ 6.9e-6;
//!   - the same with `gpu_raster.rs`'s stiff cases and colour (SH degree 3; β = 64, opacity
//!     0.999, needles with one scale 1e-3): SH and every group but means and quaternions
//!     ≤ 1e-4; means and quaternions no further from the reference than 5× the CPU reference's
//!     own f32-vs-f64 error on the same scene (needles make them ill-conditioned in f32; the
//!     colour does not — without it the CPU's f32 error is the same, 1.38e-2 / 8.08e-2).
//!     Measured: SH 1.5e-6, log-scales 2.7e-5, means 5.0e-2 and quaternions 1.7e-1, against
//!     the CPU's own f32 error of 1.4e-2 and 8.2e-2 (3.6× and 2.1×);
//!   - joint training, 16 steps on the Vulkan backend (host path: render and backward on the
//!     GPU, losses and Adam on the host) against the CPU backend: every step's loss within
//!     1e-3 relative. Measured: 1.1e-4 to 3.2e-4 (float atomics and compare-and-swap).
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{ParityScene, parity_camera, parity_scene};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, LoadOptions};
use s3tir_trainer::error::RenderError;
use s3tir_trainer::gpu::accumulate::AccumulateVariant;
use s3tir_trainer::gpu::backend::VulkanBackend;
use s3tir_trainer::gpu::raster::{GpuRasterizer, Outputs};
use s3tir_trainer::gpu::{ContextOptions, DeviceChoice, GpuContext};
use s3tir_trainer::loss::LossWeights;
use s3tir_trainer::loss::consistency::ConsistencyOptions;
use s3tir_trainer::primitive::{Group, Primitives};
use s3tir_trainer::render::{GBuffers, RenderSettings, prepare, render, render_backward};
use s3tir_trainer::train::{
    AdamParams, AdamState, Backend, CpuBackend, DeviceStep, OptimiserState, ResidentStep,
    TrainConfig, Trainer,
};

fn options(disable_float_atomics: bool) -> ContextOptions {
    ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics,
    }
}

fn lavapipe_with(disable_float_atomics: bool) -> GpuContext {
    GpuContext::new(&options(disable_float_atomics))
        .expect("lavapipe (Mesa llvmpipe) must be available: install mesa-vulkan-drivers")
}

const SETTINGS: RenderSettings = RenderSettings {
    near_m: 0.05,
    cull: true,
};

/// A random scene in front of [`parity_camera`] with `bands` bands and an SH colour of
/// `degree` (`None`: no colour); `stiff` adds `gpu_raster.rs`'s stiff cases: β = 64, opacity
/// 0.999 (the α clamp), needles (one scale 1e-3).
fn random_scene(
    seed: u64,
    n: usize,
    bands: usize,
    degree: Option<usize>,
    stiff: bool,
) -> Primitives<f64> {
    parity_scene(
        seed,
        &ParityScene {
            n,
            bands,
            sh_degree: degree,
            beta_max: 8.0,
            stiff,
            opacity_first: true,
            extras: false,
        },
    )
}

/// The same primitives without their colour.
fn without_colour<T: Clone>(p: &Primitives<T>) -> Primitives<T> {
    let mut out = p.clone();
    out.sh_degree = None;
    out.sh.clear();
    out
}

fn random_upstream(seed: u64, w: usize, h: usize) -> GBuffers<f64> {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let mut g = GBuffers::zeros(w, h, true);
    for (_, v) in g.planes_mut() {
        for x in v.iter_mut() {
            *x = r.random_range(-1.0..1.0);
        }
    }
    g
}

fn cast_buffers(g: &GBuffers<f64>) -> GBuffers<f32> {
    let mut out = GBuffers::zeros(g.width, g.height, !g.rgb.is_empty());
    for ((_, dst), (_, src)) in out.planes_mut().into_iter().zip(g.planes()) {
        *dst = src.iter().map(|v| *v as f32).collect();
    }
    out
}

/// Largest |Δ| of the RGB planes at pixels whose alpha agrees within 1e-5 (the same samples),
/// and the fraction of all RGB values within `tol`.
fn rgb_errors<T: Copy + Into<f64>>(
    gpu: &GBuffers<f32>,
    reference: &GBuffers<T>,
    tol: f64,
) -> (f64, f64, usize) {
    let npix = gpu.width * gpu.height;
    assert_eq!(gpu.rgb.len(), 3 * npix, "GPU RGB planes");
    assert_eq!(reference.rgb.len(), 3 * npix, "reference RGB planes");
    let mut worst_same = 0f64;
    let mut within = 0usize;
    let mut flips = 0usize;
    for p in 0..npix {
        let same = (f64::from(gpu.alpha[p]) - reference.alpha[p].into()).abs() <= 1e-5;
        flips += usize::from(!same);
        for c in 0..3 {
            let e = (f64::from(gpu.rgb[c * npix + p]) - reference.rgb[c * npix + p].into()).abs();
            assert!(e.is_finite(), "non-finite RGB value");
            within += usize::from(e <= tol);
            if same {
                worst_same = worst_same.max(e);
            }
        }
    }
    (worst_same, within as f64 / (3 * npix) as f64, flips)
}

#[test]
fn rgb_planes_match_cpu_reference() {
    let ctx = lavapipe_with(false);
    let raster = GpuRasterizer::new(&ctx, AccumulateVariant::best_for(ctx.capabilities())).unwrap();
    for (seed, (n, bands, degree, w, h)) in [
        (300usize, 4usize, 0usize, 96usize, 72usize),
        (300, 2, 3, 96, 72),
        (200, 0, 1, 61, 47),
        (400, 4, 3, 80, 64),
    ]
    .into_iter()
    .enumerate()
    {
        let prims = random_scene(100 + seed as u64, n, bands, Some(degree), false);
        let prims32 = prims.cast::<f32>();
        let cam = parity_camera(w, h);
        let gpu = raster
            .render(&ctx, &prims32, &cam, Outputs::All, &SETTINGS)
            .unwrap();
        let cpu32 = render(&prims32, &cam, &SETTINGS).unwrap();
        let cpu64 = render(&prims, &cam, &SETTINGS).unwrap();
        let prep = prepare(&prims, &cam, &SETTINGS).unwrap();
        assert!(
            cpu64.rgb.iter().any(|v| *v > 0.2)
                && (prep.prims.iter()).any(|pv| pv.visible && pv.colour.contains(&0.0)),
            "scene {seed} must have colour, some of it cut by the ReLU"
        );
        for (who, (worst, frac, flips)) in [
            ("f32", rgb_errors(&gpu, &cpu32, 1e-4)),
            ("f64", rgb_errors(&gpu, &cpu64, 1e-4)),
        ] {
            eprintln!(
                "scene {seed} (degree {degree}) vs {who}: RGB max |Δ| {worst:.3e} where the \
                 samples agree, {:.3} % within 1e-4, {flips} pixels with other samples",
                100.0 * frac
            );
            assert!(
                worst <= 1e-4 && frac >= 0.999,
                "scene {seed} (degree {degree}) vs {who}: RGB max |Δ| {worst:.3e} (≤ 1e-4), \
                 {:.3} % within 1e-4 (≥ 99.9 %)",
                100.0 * frac
            );
        }
        // The colour adds planes, it changes none: the same primitives without colour render
        // the same bits in every other plane.
        let plain = raster
            .render(
                &ctx,
                &without_colour(&prims32),
                &cam,
                Outputs::All,
                &SETTINGS,
            )
            .unwrap();
        assert!(plain.rgb.is_empty(), "no colour: no RGB planes");
        for ((name, a), (_, b)) in gpu.planes().iter().zip(plain.planes().iter()) {
            if *name != "rgb" {
                assert!(a == b, "scene {seed}: {name} changed with the colour");
            }
        }
        // G-buffers only: no colour.
        let gb = raster
            .render(&ctx, &prims32, &cam, Outputs::GBuffers, &SETTINGS)
            .unwrap();
        assert!(gb.rgb.is_empty(), "a G-buffers render has no RGB planes");
        assert!(gb.alpha == gpu.alpha, "G-buffers render: alpha unchanged");
    }
    raster.destroy(&ctx);
}

fn relative_l2(
    label: &str,
    gpu: &Primitives<f32>,
    reference: &Primitives<f64>,
    bound: &dyn Fn(Group) -> f64,
) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for ((name, g), (_, r)) in gpu.groups().iter().zip(reference.groups().iter()) {
        assert_eq!(g.len(), r.len(), "{label}/{name}: length");
        assert!(
            g.iter().all(|v| v.is_finite()),
            "{label}/{name}: non-finite GPU gradient"
        );
        let norm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
        let err = g
            .iter()
            .zip(r.iter())
            .map(|(a, b)| (f64::from(*a) - b).powi(2))
            .sum::<f64>()
            .sqrt();
        if norm < 1e-9 {
            assert!(
                err < 1e-6,
                "{label}/{name}: reference gradient is zero, GPU has norm {err:.3e}"
            );
            continue;
        }
        let bound = bound(*name);
        assert!(
            err / norm <= bound,
            "{label}/{name}: relative L2 error {:.3e} > {bound:.0e} (|ref| = {norm:.3e})",
            err / norm
        );
        out.push((name.to_string(), err / norm));
    }
    out
}

#[test]
fn colour_gradients_match_cpu_reference_with_and_without_float_atomics() {
    let mut worst: std::collections::BTreeMap<String, f64> = Default::default();
    for disable_float_atomics in [false, true] {
        let ctx = lavapipe_with(disable_float_atomics);
        let variant = AccumulateVariant::best_for(ctx.capabilities());
        assert_eq!(
            variant == AccumulateVariant::CompareAndSwap,
            disable_float_atomics,
            "the switch must select the fallback"
        );
        for subgroup_reduce in [true, false] {
            let raster = GpuRasterizer::with_reduction(&ctx, variant, subgroup_reduce).unwrap();
            // Scene 3: an RGB view's upstream (no thermal: the view renders its G-buffers and
            // colour only when it is not kept, the colour kernels with the thermal flag off).
            // Scene 4: the stiff cases with colour.
            for (seed, (n, bands, degree, w, h)) in [
                (120usize, 4usize, 0usize, 48usize, 40usize),
                (120, 2, 3, 48, 40),
                (150, 0, 1, 37, 29),
                (120, 2, 3, 48, 40),
                (150, 2, 3, 48, 40),
            ]
            .into_iter()
            .enumerate()
            {
                let stiff = seed == 4;
                let prims = random_scene(200 + seed as u64, n, bands, Some(degree), stiff);
                let cam = parity_camera(w, h);
                let mut up = random_upstream(seed as u64, w, h);
                if seed == 3 {
                    up.thermal.iter_mut().for_each(|g| *g = 0.0);
                }
                let want64 = render_backward(&prims, &cam, &SETTINGS, &up).unwrap();
                let prims32 = prims.cast::<f32>();
                let up32 = cast_buffers(&up);
                let want32 = render_backward(&prims32, &cam, &SETTINGS, &up32)
                    .unwrap()
                    .cast::<f64>();
                assert!(
                    want64.sh.iter().any(|g| *g != 0.0),
                    "the colour must get gradient"
                );
                // The stiff scene's own f32 conditioning: how far the CPU reference run in
                // f32 is from f64, per group (needles make means and quaternions
                // ill-conditioned; the colour does not: the same scene without it is as far).
                let cpu_f32_err: std::collections::BTreeMap<String, f64> = if stiff {
                    relative_l2("CPU f32 vs f64", &want32.cast::<f32>(), &want64, &|_| {
                        f64::INFINITY
                    })
                    .into_iter()
                    .collect()
                } else {
                    Default::default()
                };
                let bound = |group: Group| {
                    if stiff && matches!(group, Group::Means | Group::Quats) {
                        // No further from the reference than 5× the CPU's own f32 rounding.
                        (5.0 * cpu_f32_err.get(group.name()).copied().unwrap_or(0.0)).max(1e-4)
                    } else {
                        1e-4
                    }
                };
                for (g, e) in &cpu_f32_err {
                    let w = worst
                        .entry(format!("stiff: {g}, CPU f32 vs f64"))
                        .or_default();
                    *w = w.max(*e);
                }
                // Rendered first (the training step's order: the backward pass reuses the
                // view), and from scratch.
                for rendered_first in [true, false] {
                    if rendered_first {
                        raster
                            .render(&ctx, &prims32, &cam, Outputs::All, &SETTINGS)
                            .unwrap();
                    }
                    let got = raster
                        .render_backward(&ctx, &prims32, &cam, &SETTINGS, &up32)
                        .unwrap();
                    let label = format!(
                        "{variant:?}, subgroup reduce {subgroup_reduce}, scene {seed} (degree {degree}), rendered first {rendered_first}"
                    );
                    for (who, want) in [("f32", &want32), ("f64", &want64)] {
                        for (g, e) in relative_l2(&format!("{label} vs {who}"), &got, want, &bound)
                        {
                            let case = if stiff { "stiff" } else { "mild" };
                            let w = worst.entry(format!("{case}: {g} vs {who}")).or_default();
                            *w = w.max(e);
                        }
                    }
                }
            }
            raster.destroy(&ctx);
        }
        assert_eq!(
            ctx.allocated_bytes(),
            0,
            "the rasteriser must release every buffer it allocated"
        );
    }
    for (k, v) in worst {
        eprintln!("worst relative L2, {k}: {v:.3e}");
    }
}

/// A scene without colour runs the thermal kernels only (whose SPIR-V the colour branch leaves
/// unchanged) and renders the same bits as the same scene with colour in every plane it has;
/// with colour but no colour upstream, the backward pass runs the thermal kernels too and the
/// SH coefficients get zero gradient.
#[test]
fn thermal_only_scenes_run_the_thermal_kernels_only() {
    let ctx = lavapipe_with(false);
    let mut raster =
        GpuRasterizer::new(&ctx, AccumulateVariant::best_for(ctx.capabilities())).unwrap();
    raster.set_profiling(true);
    let cam = parity_camera(64, 48);
    let coloured = random_scene(7, 200, 4, Some(2), false).cast::<f32>();
    let thermal = without_colour(&coloured);
    let mut up = cast_buffers(&random_upstream(3, 64, 48));
    up.rgb.clear();
    let a = raster
        .render(&ctx, &thermal, &cam, Outputs::All, &SETTINGS)
        .unwrap();
    let b = raster
        .render(&ctx, &thermal, &cam, Outputs::All, &SETTINGS)
        .unwrap();
    assert!(a == b, "a thermal render is deterministic");
    raster
        .render_backward(&ctx, &thermal, &cam, &SETTINGS, &up)
        .unwrap();
    let kernels: Vec<String> = raster
        .take_timings()
        .into_iter()
        .map(|t| t.kernel)
        .collect();
    assert!(
        kernels.iter().any(|k| k == "raster_forward")
            && !kernels.iter().any(|k| k.ends_with("_rgb")),
        "a thermal scene runs the thermal kernels only: {kernels:?}"
    );
    let c = raster
        .render(&ctx, &coloured, &cam, Outputs::All, &SETTINGS)
        .unwrap();
    for ((name, x), (_, y)) in a.planes().iter().zip(c.planes().iter()) {
        if *name != "rgb" {
            assert!(
                x == y,
                "{name}: a scene with colour must render the same bits"
            );
        }
    }
    // Colour, no colour upstream: thermal backward kernels on the kept coloured view.
    let _ = raster.take_timings();
    let g = raster
        .render_backward(&ctx, &coloured, &cam, &SETTINGS, &up)
        .unwrap();
    let kernels: Vec<String> = raster
        .take_timings()
        .into_iter()
        .map(|t| t.kernel)
        .collect();
    assert!(
        !kernels.iter().any(|k| k.ends_with("_rgb"))
            && !kernels.iter().any(|k| k == "raster_project"),
        "no colour upstream: the kept view's thermal backward pass only: {kernels:?}"
    );
    assert!(
        g.sh.iter().all(|v| *v == 0.0),
        "no colour upstream: zero SH gradient"
    );
    raster.destroy(&ctx);
}

/// The backend renders and back-propagates colour like the CPU backend; its device and
/// resident steps (thermal losses only) refuse primitives with colour with an error instead of
/// gradients without the colour's losses.
#[test]
fn vulkan_backend_takes_colour_on_the_host_path_and_refuses_it_on_device_paths() {
    let mut vk = VulkanBackend::new(&options(false), SETTINGS).expect("lavapipe must be available");
    let mut cpu = CpuBackend { settings: SETTINGS };
    let coloured = random_scene(11, 150, 2, Some(1), false).cast::<f32>();
    let cam = parity_camera(48, 40);
    let (g_vk, g_cpu) = (
        vk.render(&coloured, &cam).unwrap(),
        cpu.render(&coloured, &cam).unwrap(),
    );
    let (worst, _, _) = rgb_errors(&g_vk, &g_cpu, 1e-4);
    assert!(worst <= 1e-4, "backend RGB planes: max |Δ| {worst:.3e}");
    assert!(
        vk.render_gbuffers(&coloured, &cam).unwrap().rgb.is_empty(),
        "G-buffers only: no colour"
    );
    let up = cast_buffers(&random_upstream(5, 48, 40));
    let d_vk = vk.backward(&coloured, &cam, &up).unwrap();
    let d_cpu = cpu.backward(&coloured, &cam, &up).unwrap().cast::<f64>();
    relative_l2("backend", &d_vk, &d_cpu, &|_| 1e-4);

    let npix = cam.width * cam.height;
    let target = vec![0.5f32; npix];
    let step = DeviceStep {
        view: 0,
        cam: &cam,
        target: &target,
        pair: None,
        weights: LossWeights::default(),
        consistency: ConsistencyOptions::default(),
        response: None,
    };
    let refused = |r: Option<Result<_, RenderError>>, call: &str| match r {
        Some(Err(e)) => assert!(
            e.to_string().contains("SH colour"),
            "{call}: the error must say why: {e}"
        ),
        Some(Ok(_)) => panic!("{call} must refuse primitives with colour"),
        None => panic!("{call} must refuse primitives with colour, not decline"),
    };
    refused(
        vk.device_step(&coloured, &step).map(|r| r.map(|_| ())),
        "device_step",
    );
    // A resident state of the same primitives without colour, then a step with colour.
    let mut thermal = without_colour(&coloured);
    let mut adam = AdamState::new(&thermal);
    let (mut accum, mut count) = (vec![0f64; thermal.len()], vec![0u32; thermal.len()]);
    let uploaded = vk
        .resident_upload(&mut OptimiserState {
            prims: &mut thermal,
            adam: &mut adam,
            grad_accum: &mut accum,
            grad_count: &mut count,
        })
        .unwrap();
    assert!(uploaded, "a thermal state goes resident");
    let resident = ResidentStep {
        losses: step,
        sizes: TrainConfig::new("unused".into()).lr,
        hp: AdamParams::default(),
        min_log_scale: -10.0,
        band_shrink: 0.0,
    };
    refused(
        vk.resident_step(&coloured, &resident)
            .map(|r| r.map(|_| ())),
        "resident_step",
    );
}

/// The synthetic thermal scene with every second view turned into an RGB view (three planes
/// made from its thermal image): a joint dataset in memory.
fn joint_scene(tmp: &std::path::Path) -> (std::path::PathBuf, Dataset) {
    let data_dir = tmp.join("scene");
    let scfg = SynthConfig {
        views: 8,
        width: 40,
        height: 30,
        f_px: 34.0,
        points: 300,
        ..SynthConfig::default()
    };
    synth::write_scene(&data_dir, &scfg).unwrap();
    let mut data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    for view in data.views.iter_mut().skip(1).step_by(2) {
        let t = view.thermal.take().unwrap();
        let rgb: Vec<f32> = (t.iter().copied())
            .chain(t.iter().map(|x| 1.0 - x))
            .chain(t.iter().map(|x| 0.25 + 0.5 * x))
            .collect();
        view.rgb = Some(rgb);
    }
    assert!(data.has_rgb() && data.has_thermal());
    (data_dir, data)
}

/// A few joint RGB + thermal training steps on the Vulkan backend (float atomics, and the
/// compare-and-swap fallback) take the CPU backend's steps: the same losses within 1e-3
/// relative over 16 steps that cross the end of the warm-up (β and bands released).
#[test]
fn joint_training_on_vulkan_follows_the_cpu_backend() {
    const STEPS: usize = 16;
    let tmp = tempfile::tempdir().unwrap();
    let (data_dir, data) = joint_scene(tmp.path());
    let config = || {
        let mut c = TrainConfig::new(data_dir.clone());
        c.iters = 200;
        c.warmup = 4;
        c.budget = 300;
        c.seed = 5;
        c.sh_degree = 1;
        c.eval_every_s = 1e9;
        c.checkpoint_every_s = 1e9;
        c.densify.from = u64::MAX;
        c.capacity.every = u64::MAX;
        c.init_opacity = 0.5;
        c
    };
    fn losses<B: Backend>(t: &mut Trainer<B>) -> Vec<f64> {
        (0..STEPS).map(|_| t.step().unwrap()).collect()
    }
    let mut cpu = Trainer::new(
        config(),
        data.clone(),
        CpuBackend::default(),
        &tmp.path().join("cpu"),
    )
    .unwrap();
    assert!(cpu.prims.sh_degree == Some(1), "a joint run has colour");
    let reference = losses(&mut cpu);
    for disable_float_atomics in [false, true] {
        let vk = VulkanBackend::new(&options(disable_float_atomics), RenderSettings::default())
            .expect("lavapipe must be available");
        let mut t = Trainer::new(
            config(),
            data.clone(),
            vk,
            &tmp.path().join(format!("vk{disable_float_atomics}")),
        )
        .unwrap();
        let initial_sh = t.prims.sh.clone();
        let got = losses(&mut t);
        let worst = got
            .iter()
            .zip(&reference)
            .map(|(a, b)| (a - b).abs() / b.abs())
            .fold(0.0, f64::max);
        eprintln!(
            "joint steps, float atomics off {disable_float_atomics}: losses {got:.5?} vs CPU {reference:.5?}, worst relative {worst:.3e}"
        );
        assert!(
            worst <= 1e-3,
            "joint training on Vulkan (float atomics off: {disable_float_atomics}): a step's \
             loss differs from the CPU backend's by {worst:.3e} relative (> 1e-3)"
        );
        // Only RGB views give the SH coefficients gradient: both modalities trained.
        t.sync_host().unwrap();
        assert!(t.prims.sh != initial_sh, "the RGB views trained the colour");
    }
}
