//! Proves density control acts with its default threshold (3DGS's 2e-4 on the view-space
//! positional gradient in NDC): on a scene seeded with far too few points for its detail it
//! clones and splits, the counts are in `capacity.json`, growth stops at the hard budget (and
//! says how many it left out) unless relocation gives the weakest primitives' places to the
//! candidates beyond it, transparent primitives are pruned; that the statistic has
//! 3DGS's units (NDC: the same world gradient at the same field of view gives the same value at
//! any resolution); and that `--time-budget` stops on time with every output written and the
//! schedule (warm-up, densification window, learning-rate decay) following the time spent;
//! and that the bands are off during the warm-up (no live slot, so no band work) and go live,
//! with fresh frequencies and zero amplitude, at its end.
//! Runs on the CPU backend; the Vulkan optimiser's statistic is held to the host's in
//! `gpu_adam.rs`. Does NOT prove density control improves a real scene (measured by hand on real data:
//! scripts/real-data/README.md).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::atomic::AtomicBool;
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, LoadOptions};
use s3tir_trainer::train::{
    CapacityReport, CpuBackend, Mode, TrainConfig, Trainer, files, view_space_gradient,
};

/// The time-budget test counts the iterations 4 s of training reach, so it takes the machine to
/// itself: it holds this lock for writing, every other test of the binary for reading (they
/// still run beside each other). Measured here (2026-11-28, 2 cores, idle machine): beside its
/// seven siblings it reached 253–296 iterations, under its floor of 300, and failed; holding
/// the machine, 346–360 (it prints its count).
static CPU: RwLock<()> = RwLock::new(());

fn shared_cpu() -> RwLockReadGuard<'static, ()> {
    CPU.read()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn whole_cpu() -> RwLockWriteGuard<'static, ()> {
    CPU.write()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The built-in wall (a sharp emissivity step and a heated pipe) at 64×48, seeded with 12
/// points: a handful of primitives for a scene with edges.
fn sparse_scene(dir: &std::path::Path) {
    let cfg = SynthConfig {
        views: 12,
        width: 64,
        height: 48,
        f_px: 53.0,
        points: 12,
        seed: 3,
    };
    synth::write_scene(dir, &cfg).unwrap();
}

/// Defaults except a short run: the densification window and cadence are the defaults'
/// proportions of a 300-iteration run (500…15 000 every 100 of 30 000 would be 5…150 every 1,
/// so every 10 keeps 10 views per statistic), and no evaluations or checkpoints mid-run.
fn short(data: &std::path::Path, mode: Mode) -> TrainConfig {
    let mut c = TrainConfig::new(data.to_path_buf());
    c.mode = mode;
    c.iters = 300;
    c.warmup = 30;
    c.densify.from = 10;
    c.densify.until = 150;
    c.densify.every = 10;
    c.eval_every_s = 1e9;
    c.checkpoint_every_s = 1e9;
    c
}

/// A CPU trainer on `cfg.data`, writing to `run`.
fn trainer(cfg: TrainConfig, run: &std::path::Path) -> Trainer<CpuBackend> {
    let data = Dataset::load(&cfg.data, &LoadOptions::default()).unwrap();
    Trainer::new(cfg, data, CpuBackend::default(), run).unwrap()
}

fn read_capacity(run: &std::path::Path) -> CapacityReport {
    serde_json::from_str(&std::fs::read_to_string(run.join(files::CAPACITY)).unwrap()).unwrap()
}

#[test]
fn default_threshold_densifies_an_under_reconstructed_scene() {
    let _cpu = shared_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    let mut cfg = short(&data_dir, Mode::Gaussian);
    assert_eq!(
        cfg.densify.grad_threshold, 2e-4,
        "this test is about the default threshold"
    );
    cfg.budget = 400; // room for 30× the seeds, and a test that stays quick
    // No per-round growth cap: it would hold 12 seeds to about one new primitive per round;
    // this test is about what the threshold selects (the cap has its own test below).
    cfg.densify.grow_frac = 0.0;
    let run = tmp.path().join("run");
    let mut t = trainer(cfg, &run);
    let start = t.prims.len();
    assert!(
        start <= 12,
        "seeded with the scene's 12 points, got {start}"
    );
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    let cap = read_capacity(&run);
    assert_eq!(
        cap.densify_rounds.len(),
        14,
        "one round every 10 iterations in [10, 150)"
    );
    assert!(
        cap.densify_cloned + cap.densify_split >= 2 * start,
        "an under-reconstructed scene must densify: {} cloned + {} split from {start} primitives",
        cap.densify_cloned,
        cap.densify_split
    );
    assert!(
        t.prims.len() >= 3 * start,
        "primitives should grow well beyond the {start} seeds, ended with {}",
        t.prims.len()
    );
    let grown: usize = cap.densify_rounds.iter().map(|r| r.cloned + r.split).sum();
    assert_eq!(
        grown,
        cap.densify_cloned + cap.densify_split,
        "capacity.json's totals are the sums of its rounds"
    );
    for r in &cap.densify_rounds {
        assert_eq!(
            r.after,
            r.before + r.cloned + r.split - r.pruned - r.relocated,
            "round at {}: a clone adds one, a split replaces one by two, a prune or a relocation removes one",
            r.iteration
        );
        assert!(r.median_statistic.is_finite() && r.median_statistic >= 0.0);
    }
}

#[test]
fn growth_stops_at_the_budget_and_reports_what_it_left_out() {
    let _cpu = shared_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    let mut cfg = short(&data_dir, Mode::S3tir);
    cfg.budget = 20;
    let run = tmp.path().join("run");
    let mut t = trainer(cfg, &run);
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    let cap = read_capacity(&run);
    for r in &cap.densify_rounds {
        assert!(
            r.after <= 20,
            "round at {}: {} > budget 20",
            r.iteration,
            r.after
        );
    }
    assert!(t.prims.len() <= 20, "budget 20 exceeded: {}", t.prims.len());
    assert!(
        cap.densify_rounds.iter().any(|r| r.over_budget > 0),
        "a full budget must show primitives left out: {:?}",
        cap.densify_rounds
    );
}

/// `grow_frac` caps what one round adds (a fraction of the primitives it starts with), and the
/// candidates it leaves out are reported like those beyond the budget.
#[test]
fn growth_per_round_is_capped() {
    let _cpu = shared_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    let mut cfg = short(&data_dir, Mode::Gaussian);
    cfg.budget = 400;
    cfg.densify.grow_frac = 0.25;
    let run = tmp.path().join("run");
    let mut t = trainer(cfg, &run);
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    let cap = read_capacity(&run);
    for r in &cap.densify_rounds {
        let limit = (0.25 * r.before as f64).ceil() as usize;
        assert!(
            r.cloned + r.split <= limit,
            "round at {}: {} cloned + {} split from {} primitives, cap {limit}",
            r.iteration,
            r.cloned,
            r.split,
            r.before
        );
        assert_eq!(
            r.relocated, 0,
            "the budget never filled: nothing to relocate"
        );
    }
    assert!(
        cap.densify_rounds
            .iter()
            .any(|r| r.over_budget > 0 && r.after < 400),
        "the cap, not the budget, must have left candidates out: {:?}",
        cap.densify_rounds
    );
    assert!(
        t.prims.len() > 12,
        "a capped round still grows an under-reconstructed scene: {} primitives",
        t.prims.len()
    );
}

/// With the budget full, a round removes up to `relocate_frac` of the primitives — the weakest
/// by opacity — and clones or splits as many candidates in their place; with 0 it does not.
#[test]
fn a_full_budget_relocates_its_weakest_primitives() {
    let _cpu = shared_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    for frac in [0.0, 0.25] {
        let mut cfg = short(&data_dir, Mode::Gaussian);
        cfg.iters = 22; // one round, at iteration 10 (the window ends at iters/2 = 11)
        cfg.budget = 12; // the seeds fill it
        cfg.densify.relocate_frac = frac;
        cfg.densify.grow_frac = 0.0;
        let run = tmp.path().join(format!("run-{frac}"));
        let mut t = trainer(cfg, &run);
        let n = t.prims.len();
        assert_eq!(n, 12, "the scene's 12 seeds fill the budget");
        // Three weak primitives: opacity ≈ 0.018, above the 0.005 prune threshold, so only a
        // relocation removes them.
        for i in 0..3 {
            t.prims.opacity_logits[i] = -4.0;
        }
        let seeds: Vec<[f32; 3]> = (0..n).map(|i| t.prims.mean(i)).collect();
        let dist = |a: [f32; 3], b: [f32; 3]| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        let closest = seeds
            .iter()
            .enumerate()
            .flat_map(|(i, a)| seeds[i + 1..].iter().map(move |b| dist(*a, *b)))
            .fold(f32::INFINITY, f32::min);
        assert!(
            closest > 0.05,
            "seeds {closest} m apart: too close to tell apart"
        );
        while t.iteration <= 10 {
            t.step().unwrap();
        }
        let cap = t.capacity_report();
        assert_eq!(cap.densify_rounds.len(), 1, "{:?}", cap.densify_rounds);
        let r = &cap.densify_rounds[0];
        assert!(
            r.over_threshold >= 3,
            "the sparse scene has candidates: {r:?}"
        );
        assert!(t.prims.len() <= 12, "budget 12 exceeded: {}", t.prims.len());
        let survives = |s: [f32; 3]| (0..t.prims.len()).any(|i| dist(t.prims.mean(i), s) < 0.01);
        if frac == 0.0 {
            assert_eq!(r.relocated, 0, "relocation off: {r:?}");
            assert_eq!(
                r.over_budget, r.over_threshold,
                "growth stops at the budget: {r:?}"
            );
            assert!(
                seeds[..3].iter().all(|&s| survives(s)),
                "without relocation the weak primitives stay"
            );
        } else {
            assert_eq!(r.relocated, 3, "a quarter of 12 relocated: {r:?}");
            assert_eq!(
                r.cloned + r.split,
                3,
                "one candidate in each freed place: {r:?}"
            );
            assert!(
                seeds[..3].iter().all(|&s| !survives(s)),
                "the three weakest primitives are the ones removed"
            );
            let strong_left = seeds[3..].iter().filter(|&&s| survives(s)).count();
            assert!(
                strong_left + r.split >= 9,
                "the nine stronger primitives stay unless split (a clone keeps its parent's \
                 centre, a split replaces it): {strong_left} left, {} split",
                r.split
            );
        }
        assert_eq!(
            r.after,
            r.before + r.cloned + r.split - r.pruned - r.relocated
        );
        assert_eq!(cap.densify_relocated, r.relocated, "capacity.json's total");
    }
}

#[test]
fn transparent_primitives_are_pruned() {
    let _cpu = shared_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    let mut cfg = short(&data_dir, Mode::Gaussian);
    cfg.iters = 22; // one round, at iteration 10 (the window ends at iters/2 = 11)
    cfg.densify.grad_threshold = f64::INFINITY; // nothing grows: only pruning acts
    let run = tmp.path().join("run");
    let mut t = trainer(cfg, &run);
    let n = t.prims.len();
    // Three primitives made transparent (opacity ≈ 5e-5, under the 0.005 default): a few
    // steps of Adam at lr 0.05 cannot bring them back above it.
    for i in 0..3 {
        t.prims.opacity_logits[i] = -10.0;
    }
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    let cap = read_capacity(&run);
    assert_eq!(cap.densify_rounds.len(), 1, "{:?}", cap.densify_rounds);
    assert_eq!(cap.densify_pruned, 3, "the three transparent primitives");
    assert_eq!(t.prims.len(), n - 3);
    assert!(
        t.prims.opacity_logits.iter().all(|&l| l > -9.0),
        "no transparent primitive left"
    );
}

#[test]
fn the_statistic_is_in_ndc_whatever_the_resolution() {
    let _cpu = shared_cpu();
    let cam = |w: usize, f: f64| PinholeCamera {
        fx_px: f,
        fy_px: f,
        cx_px: w as f64 / 2.0,
        cy_px: 0.375 * w as f64,
        width: w,
        height: w * 3 / 4,
        cam_from_world: s3tir_calib::Rigid3::IDENTITY,
    };
    let mean = [0.1, -0.2, 4.0];
    // A world gradient along x (the camera's x: identity pose) at depth 4: dL/du = g·z/fx,
    // dL/dndc = dL/du · W/2.
    let g = [1e-4, 0.0, 0.0];
    let low = view_space_gradient(&cam(320, 300.0), mean, g);
    assert!(
        (low - 1e-4 * 4.0 / 300.0 * 160.0).abs() < 1e-12,
        "expected g·z/fx·W/2, got {low}"
    );
    // Twice the resolution at the same field of view: the same NDC statistic.
    let high = view_space_gradient(&cam(640, 600.0), mean, g);
    assert!((high - low).abs() < 1e-12, "{high} vs {low}");
    // Depth (the camera's z) does not move the projection: no statistic.
    let along = view_space_gradient(&cam(320, 300.0), mean, [0.0, 0.0, 1.0]);
    assert_eq!(
        along, 0.0,
        "a gradient along the viewing axis has no image-plane part"
    );
}

#[test]
fn time_budget_stops_on_time_with_outputs_and_a_scaled_schedule() {
    let _cpu = whole_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    let mut cfg = TrainConfig::new(data_dir.clone());
    cfg.time_budget_s = Some(4.0);
    cfg.eval_every_s = 1.0;
    cfg.checkpoint_every_s = 1e9;
    let run = tmp.path().join("run");
    let mut t = trainer(cfg, &run);
    let mut evals = 0;
    t.run(&AtomicBool::new(false), &mut |e| {
        if let s3tir_trainer::train::Event::Eval(_) = e {
            evals += 1;
        }
    })
    .unwrap();
    eprintln!(
        "time budget: {} iterations in {:.2} s of training",
        t.iteration, t.train_seconds
    );
    assert!(
        (4.0..=4.2).contains(&t.train_seconds),
        "a 4 s budget must stop within 5 %: trained {:.3} s",
        t.train_seconds
    );
    assert!(t.finished() && t.progress() == 1.0);
    assert!(
        evals >= 4,
        "evaluations every second of training, got {evals}"
    );
    for f in [
        files::PLY,
        files::EVAL,
        files::CAPACITY,
        files::METRICS_CSV,
        files::CHECKPOINT,
    ] {
        assert!(
            run.join(f).exists(),
            "{f} written at the end of a budgeted run"
        );
    }
    // The schedule followed the time: the nominal 30 000-iteration schedule's densification
    // window (500…15 000 every 100) and warm-up (3 000: 10 %) fell inside 4 s, so the run
    // densified, ended its warm-up, and stopped densifying at half the time.
    assert!(
        t.iteration >= 300,
        "this scene trains at hundreds of steps/s on one core; {} iterations in 4 s",
        t.iteration
    );
    let cap = read_capacity(&run);
    assert!(
        !cap.densify_rounds.is_empty(),
        "{} iterations in 4 s: the scaled window must have run density control",
        t.iteration
    );
    for r in &cap.densify_rounds {
        assert!(
            r.seconds < 2.0 + 0.1,
            "no density control in the second half of the budget (round at {:.2} s)",
            r.seconds
        );
    }
    let ended = t
        .warmup_ended_at()
        .expect("the warm-up ends at 10 % of the budget");
    assert!(
        ended > 0 && ended < t.iteration,
        "warm-up ended at iteration {ended} of {}",
        t.iteration
    );
}

#[test]
fn bands_are_off_during_the_warm_up_and_live_after_it() {
    let _cpu = shared_cpu();
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    sparse_scene(&data_dir);
    let mut cfg = short(&data_dir, Mode::S3tir);
    cfg.densify.every = 0;
    let mut t = trainer(cfg, &tmp.path().join("run"));
    let m = t.cfg.bands;
    assert_eq!(m, 4);
    while t.iteration < 30 {
        assert!(
            t.prims.bands == 0 && t.adam.m.bands == 0 && t.adam.v.bands == 0,
            "iteration {}: no band storage during the warm-up (30): M = {}",
            t.iteration,
            t.prims.bands
        );
        assert!(
            t.prims.band_count.iter().all(|&c| c == 0) && t.prims.band_freq.is_empty(),
            "no band slot, live or idle"
        );
        t.step().unwrap();
    }
    // The step at iteration 30 ends the warm-up.
    t.step().unwrap();
    assert_eq!(t.warmup_ended_at(), Some(30));
    assert_eq!(
        (t.prims.bands, t.adam.m.bands, t.adam.v.bands),
        (m, m, m),
        "the storage grows to M at the warm-up's end"
    );
    assert_eq!(
        t.capacity_report().bands_initial,
        m,
        "the report's initial M is the run's"
    );
    assert!(
        t.prims.band_count.iter().all(|&c| c as usize == m),
        "every slot live after the warm-up"
    );
    assert!(
        t.prims
            .band_freq
            .chunks(3)
            .all(|f| f.iter().any(|&x| x != 0.0)),
        "every live band has a frequency"
    );
    // One step of Adam moves an amplitude by at most its learning rate (0.0025).
    assert!(
        t.prims.band_amp.iter().all(|a| a.abs() <= 0.003),
        "amplitudes start at zero: {:?}",
        &t.prims.band_amp[..8]
    );
}
