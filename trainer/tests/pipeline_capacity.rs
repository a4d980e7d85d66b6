//! Proves the "leave out what the scene does not need" rules of the training loop: negligible
//! bands are dropped and the band storage compacts (M shrinks, memory falls, training goes on),
//! colour is not allocated without RGB, the consistency loss is reported as skipped when no view
//! pair overlaps enough (and as not needed in 3dgs mode), the primitive budget holds through
//! density control, and the row-wise parameter helpers keep rows aligned; that dropped band
//! slots never grow back (the per-primitive `band_count` mask: Adam leaves those slots at zero
//! whatever gradient they get, and the mask survives checkpoints and the PLY), and that
//! primitives with β ≈ 2 and no live band are snapped to β = 2 and frozen on the cheap Gaussian
//! path (3dgs mode: all of them from the start); that the band grant keeps bands only on the
//! primitives with the largest band gradients within the budget, and leaves them out entirely
//! when no gradient exceeds λ. Does NOT measure step time savings (timing
//! asserts are not allowed in tests; `capacity.json` and `benches/cpu_render.rs` carry them).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::atomic::AtomicBool;

use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, LoadOptions};
use s3tir_trainer::primitive::{BETA_RAW_FROZEN, PrimitiveInit, Primitives, is_beta_frozen};
use s3tir_trainer::train::params::{compact_bands, gather};
use s3tir_trainer::train::{
    AdamParams, AdamState, BandRoundKind, CpuBackend, GroupLrs, Mode, TrainConfig, Trainer,
};

fn scene(dir: &std::path::Path) {
    let cfg = SynthConfig {
        views: 9,
        width: 24,
        height: 18,
        f_px: 20.0,
        points: 200,
        seed: 2,
    };
    synth::write_scene(dir, &cfg).unwrap();
}

fn quick(data: &std::path::Path, mode: Mode) -> TrainConfig {
    let mut c = TrainConfig::new(data.to_path_buf());
    c.mode = mode;
    c.iters = 40;
    c.warmup = 10;
    c.budget = 60;
    c.eval_every_s = 1e9;
    c.checkpoint_every_s = 1e9;
    c.densify.from = 5;
    c.densify.every = 5;
    c.densify.grad_threshold = 0.0; // densify everything it can: the budget must still hold
    c
}

#[test]
fn negligible_bands_are_dropped_and_storage_compacts() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    scene(&data_dir);
    let mut cfg = quick(&data_dir, Mode::S3tir);
    cfg.capacity.every = 10;
    cfg.capacity.band_amp_threshold = 10.0; // every band is "negligible"
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let mut t = Trainer::new(cfg, data, CpuBackend::default(), &tmp.path().join("run")).unwrap();
    assert_eq!(t.prims.bands, 0, "no band storage during the warm-up");
    while t.warmup_ended_at().is_none() {
        t.step().unwrap();
    }
    assert_eq!(t.prims.bands, 4, "M slots from the warm-up's end");
    let before = t.memory_bytes() / t.prims.len();
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    let cap = t.capacity_report();
    assert_eq!(t.iteration, 40, "training continues after compaction");
    assert_eq!(t.prims.bands, 0, "band storage compacted to M = 0");
    assert_eq!((cap.bands_initial, cap.bands_now), (4, 0));
    assert_eq!(
        cap.band_bytes_saved,
        4 * 5 * 4 * 3 * t.prims.len(),
        "saved bytes"
    );
    assert!(cap.step_ms_before_compaction.is_some() && cap.step_ms_after_compaction.is_some());
    assert!(
        t.memory_bytes() / t.prims.len() < before,
        "memory per primitive {} should fall below {before}",
        t.memory_bytes() / t.prims.len(),
    );
    assert!(t.prims.len() <= 60, "budget 60 exceeded: {}", t.prims.len());
    assert!(
        !cap.colour_allocated && t.prims.sh.is_empty(),
        "no RGB → no colour"
    );
    let saved: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("run/capacity.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(saved["bands_now"], 0, "capacity.json: {saved}");
}

#[test]
fn consistency_is_skipped_without_overlap_and_not_needed_in_3dgs_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    scene(&data_dir);
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let mut cfg = quick(&data_dir, Mode::S3tir);
    cfg.capacity.min_pair_overlap = 1.01; // no pair can qualify
    let mut t = Trainer::new(
        cfg,
        data.clone(),
        CpuBackend::default(),
        &tmp.path().join("a"),
    )
    .unwrap();
    let cap = t.capacity_report();
    assert_eq!(cap.consistency_pairs, 0);
    assert!(
        cap.consistency_reason.contains("skipped"),
        "{}",
        cap.consistency_reason
    );
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    assert_eq!(t.iteration, 40);

    let t = Trainer::new(
        quick(&data_dir, Mode::S3tir),
        data.clone(),
        CpuBackend::default(),
        &tmp.path().join("b"),
    )
    .unwrap();
    assert!(
        t.capacity_report().consistency_pairs > 0,
        "the synthetic views overlap"
    );
    let t = Trainer::new(
        quick(&data_dir, Mode::Gaussian),
        data,
        CpuBackend::default(),
        &tmp.path().join("c"),
    )
    .unwrap();
    let cap = t.capacity_report();
    assert!(
        cap.consistency_reason.contains("not needed"),
        "{}",
        cap.consistency_reason
    );
    assert_eq!(t.prims.bands, 0, "3dgs mode has no bands");
    assert_eq!(
        cap.gaussian_path_primitives,
        t.prims.len(),
        "all primitives on the Gaussian path"
    );
}

#[test]
fn row_helpers_keep_rows_aligned() {
    let mut p = Primitives::<f64>::new(3, Some(1));
    for i in 0..4 {
        let x = i as f64;
        p.push(&PrimitiveInit {
            mean_m: [x, x, x],
            omega_low: x,
            bands: vec![
                (0.1 * x, [x; 3], 1.0),
                (0.0, [0.0; 3], 0.0),
                (0.3 * x, [2.0 * x; 3], 2.0),
            ],
            sh: vec![[x; 3]; 4],
            ..Default::default()
        });
    }
    let p = p.cast::<f32>();
    let g = gather(&p, &[3, 1, 1]);
    g.validate().unwrap();
    assert_eq!(g.omega_low, vec![3.0, 1.0, 1.0]);
    assert_eq!(&g.sh[0..3], &[3.0; 3], "SH rows follow");
    let keep = vec![vec![2, 0], vec![2], vec![], vec![0, 2]];
    let c = compact_bands(&p, &keep, 2);
    c.validate().unwrap();
    assert_eq!(c.bands, 2);
    assert_eq!(
        c.band_amp[0..2],
        [0.0, 0.0],
        "primitive 0: both bands were 0·x"
    );
    assert_eq!(
        c.band_amp[6..8],
        [p.band_amp[9], p.band_amp[11]],
        "primitive 3 keeps bands 0 and 2"
    );
    assert_eq!(c.band_freq[6 * 3..6 * 3 + 3], p.band_freq[9 * 3..9 * 3 + 3]);
    assert_eq!(
        c.band_amp[2..4],
        [p.band_amp[5], 0.0],
        "primitive 1 keeps band 2, pads with 0"
    );
}

#[test]
fn colour_is_allocated_and_trained_when_rgb_views_exist() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    scene(&data_dir);
    // Add an RGB twin of every view (same pose and camera; a red/blue split image).
    let images = data_dir.join("sparse/0/images.txt");
    let text = std::fs::read_to_string(&images).unwrap();
    let mut extra = String::new();
    for line in text.lines().filter(|l| l.ends_with(".png")) {
        let t: Vec<&str> = line.split_whitespace().collect();
        let name = format!("rgb_{}", t[9]);
        let id: u32 = t[0].parse::<u32>().unwrap() + 100;
        extra.push_str(&format!("{id} {} {name}\n\n", t[1..9].join(" ")));
        let img = image::RgbImage::from_fn(24, 18, |x, _| {
            if x < 12 {
                image::Rgb([200, 30, 30])
            } else {
                image::Rgb([30, 30, 200])
            }
        });
        img.save(data_dir.join("images").join(&name)).unwrap();
    }
    std::fs::write(&images, format!("{text}{extra}")).unwrap();
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    assert!(data.has_rgb() && data.has_thermal());
    assert_eq!(data.views.iter().filter(|v| v.rgb.is_some()).count(), 9);
    assert!(
        data.range.unwrap().radiometric(),
        "the thermal range ignores RGB views"
    );
    let mut t = Trainer::new(
        quick(&data_dir, Mode::S3tir),
        data,
        CpuBackend::default(),
        &tmp.path().join("run"),
    )
    .unwrap();
    assert!(t.capacity_report().colour_allocated);
    assert_eq!(t.prims.sh_degree, Some(0));
    let sh0 = t.prims.sh.clone();
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    assert_eq!(t.iteration, 40);
    assert!(t.prims.sh.iter().all(|v| v.is_finite()));
    assert_ne!(t.prims.sh.len(), 0);
    let moved = sh0.len() != t.prims.sh.len() || sh0.iter().zip(&t.prims.sh).any(|(a, b)| a != b);
    assert!(moved, "SH colour should be trained on the RGB views");
}

/// Every dropped slot (j ≥ band_count[i]) holds exact zeros; returns how many primitives have
/// some but not all slots live.
fn dropped_slots_are_zero(p: &Primitives<f32>, when: &str) -> usize {
    let m = p.bands;
    let mut partial = 0;
    for i in 0..p.len() {
        let live = p.live_bands(i);
        if live > 0 && live < m {
            partial += 1;
        }
        for j in live..m {
            let s = m * i + j;
            let vals = [
                p.band_amp[s],
                p.band_phase[s],
                p.band_freq[3 * s],
                p.band_freq[3 * s + 1],
                p.band_freq[3 * s + 2],
            ];
            assert!(
                vals.iter().all(|v| *v == 0.0),
                "{when}: primitive {i} slot {j} (live {live} of {m}) regrew: {vals:?}"
            );
        }
    }
    partial
}

#[test]
fn adam_never_updates_dropped_slots_or_a_frozen_beta() {
    let mut p = Primitives::<f64>::new(2, None);
    for _ in 0..2 {
        p.push(&PrimitiveInit {
            beta: 3.0,
            bands: vec![(0.2, [1.0; 3], 0.5), (0.0, [0.0; 3], 0.0)],
            ..Default::default()
        });
    }
    let mut p = p.cast::<f32>();
    p.band_count = vec![1, 2];
    p.beta_raw[1] = BETA_RAW_FROZEN as f32;
    let mut grads = p.zeros_like();
    for (_, g) in grads.groups_mut() {
        g.fill(1.0);
    }
    let lrs = GroupLrs {
        means: 0.1,
        log_scales: 0.1,
        quats: 0.1,
        opacity_logits: 0.1,
        beta: 0.1,
        omega_low: 0.1,
        band_amp: 0.1,
        band_freq: 0.1,
        band_phase: 0.1,
        sh: 0.1,
    };
    let mut adam = AdamState::new(&p);
    let before = p.clone();
    for _ in 0..5 {
        adam.step(&mut p, &grads, &lrs, &AdamParams::default());
    }
    assert_eq!(
        (p.band_amp[1], p.band_phase[1], &p.band_freq[3..6]),
        (0.0, 0.0, &[0.0f32; 3][..]),
        "primitive 0's dropped slot 1 stays zero"
    );
    assert_eq!(
        (adam.m.band_amp[1], adam.v.band_amp[1]),
        (0.0, 0.0),
        "moments held"
    );
    assert!(p.band_amp[0] != before.band_amp[0], "live slot 0 trains");
    assert!(
        p.band_amp[3] != before.band_amp[3],
        "primitive 1's slot 1 is live and trains"
    );
    assert_eq!(
        p.beta_raw[1], BETA_RAW_FROZEN as f32,
        "a frozen β stays frozen"
    );
    assert!(p.beta_raw[0] != before.beta_raw[0], "a learnable β trains");
}

#[test]
fn dropped_band_slots_never_regrow_and_the_mask_is_saved() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    scene(&data_dir);
    let mut cfg = quick(&data_dir, Mode::S3tir);
    cfg.iters = 60;
    cfg.capacity.every = 10;
    cfg.capacity.band_amp_threshold = 0.012;
    cfg.lr.beta = 0.1;
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let run = tmp.path().join("run");
    let mut t = Trainer::new(cfg, data, CpuBackend::default(), &run).unwrap();
    let (mut partial_seen, mut frozen_seen) = (0, 0);
    while t.iteration < 60 {
        t.step().unwrap();
        let when = format!("after iteration {}", t.iteration);
        partial_seen = partial_seen.max(dropped_slots_are_zero(&t.prims, &when));
        frozen_seen = frozen_seen.max(t.capacity_report().gaussian_path_primitives);
    }
    let cap = t.capacity_report();
    eprintln!(
        "M {} → {}, partial primitives seen {partial_seen}, dropped slots {}, Gaussian path {} of {}",
        cap.bands_initial,
        cap.bands_now,
        cap.band_slots_dropped,
        cap.gaussian_path_primitives,
        t.prims.len()
    );
    assert!(
        partial_seen > 0,
        "the test must see primitives with some (not all) bands dropped"
    );
    assert!(
        frozen_seen > 0,
        "primitives with β ≈ 2 and no band must be frozen on the Gaussian path"
    );
    for i in 0..t.prims.len() {
        let raw = f64::from(t.prims.beta_raw[i]);
        if is_beta_frozen(raw) {
            assert_eq!(
                t.prims.live_bands(i),
                0,
                "frozen primitive {i} has no live band"
            );
        }
    }
    // The mask survives a checkpoint and the PLY.
    t.save_checkpoint().unwrap();
    let ck = s3tir_trainer::checkpoint::load(&run.join("checkpoint.json")).unwrap();
    let back: Primitives<f32> = ck.primitives;
    assert_eq!(
        back.band_count, t.prims.band_count,
        "band_count through the checkpoint"
    );
    assert_eq!(
        back.beta_raw, t.prims.beta_raw,
        "frozen β through the checkpoint"
    );
    let ply = tmp.path().join("m.ply");
    s3tir_trainer::ply::write_ply(&ply, &t.prims).unwrap();
    let back = s3tir_trainer::ply::read_ply(&ply).unwrap();
    assert_eq!(
        back.band_count, t.prims.band_count,
        "band_count through the PLY"
    );
    assert_eq!(back, t.prims, "PLY round trip");
}

#[test]
fn gaussian_mode_runs_every_primitive_on_the_frozen_gaussian_path() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    scene(&data_dir);
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    // The CPU step timing is opt-in (six CPU passes at the end of every run otherwise).
    let mut cfg = quick(&data_dir, Mode::Gaussian);
    cfg.cpu_timing = true;
    let mut t = Trainer::new(cfg, data, CpuBackend::default(), &tmp.path().join("run")).unwrap();
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    assert!(
        t.prims
            .beta_raw
            .iter()
            .all(|&r| r == BETA_RAW_FROZEN as f32),
        "3dgs mode: β frozen at exactly 2 for the whole run"
    );
    let cap: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("run/capacity.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        cap["gaussian_path_primitives"].as_u64(),
        Some(t.prims.len() as u64),
        "capacity.json: {cap}"
    );
    assert!(
        cap["cpu_step_ms_with_shortcuts"].as_f64().is_some()
            && cap["cpu_step_ms_general_path"].as_f64().is_some(),
        "capacity.json reports the CPU step time with and without shortcuts: {cap}"
    );
}

/// One run of the quick scene in s3tir mode with a capacity check every 10 iterations and the
/// given grant settings; returns the trainer after the run.
fn granted_run(dir: &std::path::Path, band_l1: f64, band_budget: f64) -> Trainer<CpuBackend> {
    let data_dir = dir.join("scene");
    if !data_dir.exists() {
        scene(&data_dir);
    }
    let mut cfg = quick(&data_dir, Mode::S3tir);
    cfg.capacity.every = 10;
    cfg.capacity.band_l1 = band_l1;
    cfg.capacity.band_budget = band_budget;
    // Density control would add band holders after the grant (children inherit bands): the
    // grant's own effect is what is measured here.
    cfg.densify.every = 0;
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let run = dir.join(format!("run-{band_l1}-{band_budget}"));
    let mut t = Trainer::new(cfg, data, CpuBackend::default(), &run).unwrap();
    t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    t
}

#[test]
fn bands_are_granted_to_the_largest_band_gradients_within_the_budget() {
    let tmp = tempfile::tempdir().unwrap();
    // No budget: every primitive with a measured band gradient keeps its bands (the mechanism
    // off, as before the grant existed).
    let all = granted_run(tmp.path(), 0.0, 1.0);
    let round = all.capacity_report().band_rounds[0].clone();
    assert_eq!(round.kind, BandRoundKind::Grant, "{round:?}");
    assert!(
        round.holders_after == round.over_threshold && round.holders_after > 0,
        "no budget, threshold 0: every primitive with a band gradient keeps its bands \
         ({round:?})"
    );
    // A quarter: at most a quarter of the primitives keep bands, and they are the ones with the
    // largest band gradients (the unit test of `band_grant` checks the order).
    let quarter = granted_run(tmp.path(), 0.0, 0.25);
    let cap = quarter.capacity_report();
    let round = &cap.band_rounds[0];
    let n = quarter.prims.len();
    assert_eq!(round.budget, n / 4, "{round:?}");
    assert!(
        round.holders_after <= n / 4 && round.holders_after > 0,
        "a quarter of {n} primitives may keep bands: {round:?}"
    );
    assert!(
        cap.band_holders <= n / 4,
        "holders at the end {} over the budget {}",
        cap.band_holders,
        n / 4
    );
    let refused = (0..n).filter(|&i| quarter.prims.live_bands(i) == 0).count();
    assert!(
        refused >= n - n / 4,
        "refused primitives must lose every band slot: {refused} of {n} have none"
    );
    let saved: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("run-0-0.25/capacity.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        saved["band_rounds"][0]["kind"], "grant",
        "capacity.json: {saved}"
    );
}

#[test]
fn a_scene_whose_band_gradients_stay_under_lambda_trains_without_bands() {
    let tmp = tempfile::tempdir().unwrap();
    // λ far above any gradient this scene gives: the guard leaves the bands out entirely.
    let t = granted_run(tmp.path(), 1e6, 1.0);
    let cap = t.capacity_report();
    assert_eq!(
        t.iteration, 40,
        "training goes on after the bands are left out"
    );
    assert_eq!(t.prims.bands, 0, "band storage compacted to M = 0");
    assert_eq!(cap.band_rounds[0].holders_after, 0, "{:?}", cap.band_rounds);
    assert!(
        cap.notes.iter().any(|n| n.contains("bands left out")),
        "the run says why: {:?}",
        cap.notes
    );
}
