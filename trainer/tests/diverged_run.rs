//! Proves: a run whose state turns non-finite (NaN injected into the primitives between two
//! runs of the loop, as a diverging step would leave them) stops with a clear error and never
//! overwrites its last good checkpoint (JSON has no NaN: before this guard serde_json wrote
//! `null` and the checkpoint could no longer be resumed); the checkpoint writer refuses NaN;
//! starting a run in a folder that holds a metrics log but no checkpoint keeps that log aside
//! instead of deleting it. Does not make a real configuration diverge (no default does).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::atomic::AtomicBool;

use s3tir_trainer::checkpoint::{self, CheckpointError};
use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, LoadOptions};
use s3tir_trainer::train::{CpuBackend, Outcome, TrainConfig, TrainError, Trainer};

fn scene(dir: &std::path::Path) -> Dataset {
    let cfg = SynthConfig {
        views: 6,
        width: 24,
        height: 18,
        f_px: 20.0,
        points: 80,
        seed: 4,
    };
    synth::write_scene(dir, &cfg).unwrap();
    Dataset::load(dir, &LoadOptions::default()).unwrap()
}

fn config(data: &std::path::Path, iters: u64) -> TrainConfig {
    let mut c = TrainConfig::new(data.to_path_buf());
    c.iters = iters;
    c.warmup = 2;
    c.budget = 100;
    c.eval_every_s = 1e9;
    c.checkpoint_every_s = 0.0; // a checkpoint after every step: the guard must hold each time
    c
}

#[test]
fn a_nan_stops_the_run_and_the_last_checkpoint_stays_resumable() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    let data = scene(&data_dir);
    let run = tmp.path().join("run");
    let stop = AtomicBool::new(false);
    let mut t = Trainer::new(
        config(&data_dir, 3),
        data.clone(),
        CpuBackend::default(),
        &run,
    )
    .unwrap();
    assert_eq!(t.run(&stop, &mut |_| {}).unwrap(), Outcome::Finished);
    let good = checkpoint::load(&run.join("checkpoint.json")).unwrap();
    assert_eq!(good.iteration, 3);

    // (1) NaN in every target image: the first loss is NaN, the loop's guard stops it.
    // (2) NaN temperatures, (3) one NaN mean: the renderer clamps or culls them, the loss stays
    // finite, the parameters do not: the checkpoint writer refuses them.
    type Poison = fn(&mut Trainer<CpuBackend>);
    let cases: [(&str, Poison, bool); 3] = [
        (
            "NaN target images",
            |t| {
                for v in &mut t.data.views {
                    if let Some(th) = v.thermal.as_mut() {
                        th.fill(f32::NAN);
                    }
                }
            },
            true,
        ),
        (
            "NaN temperatures",
            |t| t.prims.omega_low.fill(f32::NAN),
            false,
        ),
        ("one NaN mean", |t| t.prims.means[0] = f32::NAN, false),
    ];
    for (what, poison, loss_guard) in cases {
        let mut t = Trainer::resume(
            config(&data_dir, 8),
            data.clone(),
            CpuBackend::default(),
            &run,
        )
        .unwrap();
        poison(&mut t);
        let err = match t.run(&stop, &mut |_| {}) {
            Ok(o) => panic!("{what}: a poisoned run must fail, it ended {o:?}"),
            Err(e) => e,
        };
        match (&err, loss_guard) {
            (
                TrainError::NonFinite {
                    iteration, loss, ..
                },
                true,
            ) => assert!(
                *iteration == 4 && loss.is_nan(),
                "{what}: the first resumed step (iteration 4; 3 were done) has a NaN loss, got \
                 {loss} at {iteration}"
            ),
            (TrainError::Checkpoint(CheckpointError::NonFinite { group, .. }), false) => assert!(
                group.starts_with("primitives.") || group.starts_with("adam_"),
                "{what}: names the parameter group: {group}"
            ),
            (other, _) => panic!(
                "{what}: expected the {} guard, got: {other}",
                if loss_guard { "loss" } else { "checkpoint" }
            ),
        }
        let text = err.to_string();
        println!("{what}: {text}");
        assert!(
            text.contains("diverged") && text.contains(&run.display().to_string()),
            "{what}: the error says the run diverged and names it: {text}"
        );
        let kept = checkpoint::load(&run.join("checkpoint.json"))
            .unwrap_or_else(|e| panic!("{what}: the last checkpoint must stay readable: {e}"));
        assert_eq!(
            kept, good,
            "{what}: the checkpoint on disk is the last good one, unchanged"
        );
    }

    // The kept checkpoint resumes and trains on.
    let mut t = Trainer::resume(config(&data_dir, 5), data, CpuBackend::default(), &run).unwrap();
    assert_eq!(t.run(&stop, &mut |_| {}).unwrap(), Outcome::Finished);
    assert_eq!(
        checkpoint::load(&run.join("checkpoint.json"))
            .unwrap()
            .iteration,
        5
    );
}

#[test]
fn a_metrics_log_without_a_checkpoint_is_kept_aside_not_deleted() {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    let data = scene(&data_dir);
    let run = tmp.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("metrics.csv"), "someone's numbers\n").unwrap();
    let _t = Trainer::new(config(&data_dir, 1), data, CpuBackend::default(), &run).unwrap();
    assert_eq!(
        std::fs::read_to_string(run.join("metrics.csv.1")).unwrap(),
        "someone's numbers\n",
        "the old log must be kept as metrics.csv.1"
    );
    assert!(
        !run.join("metrics.csv").exists(),
        "the new run starts its own log"
    );
}
