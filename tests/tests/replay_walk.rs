//! Replay in CI: the committed walk session `tests/data/sim_walk_tags/walk.mcap`
//! becomes the same posed dataset every run, and trains.
//!
//! The session: a 6 s hand-held walk of the simulated rig (Lepton 3.5 + RGB) around the walk
//! scene, whose room carries AprilTags (`s3tir-firmware-sim` `fiducials`), recorded by
//! `s3tir-capture --device sim:lepton35 --rgb sim --walk handheld --duration-s 6 --calibration
//! cal.yaml` (the rig's true calibration attached). Beside it, the simulator's `tags.toml`
//! (the tag map) and `truth.json`.
//!
//! Proves:
//! - `s3tir-capture export --dataset --tags` (capture → `s3tir-calib poses`, the AprilTag fast
//!   path: no COLMAP) writes a dataset whose images, model and hold-out list have the digest
//!   pinned below, on every run and machine of this kind;
//! - its poses are in the truth's world and metres (median rotation < 0.5°, centre < 1 % of
//!   the scene extent, no alignment);
//! - `s3tir-train SESSION.mcap --tags` poses the same dataset (same digest) and trains 200
//!   steps whose held-out PSNR is finite and above 15 dB.
//!
//! When the digest changes on purpose (the poses stage or the PNG writer changed), the
//! failure message prints the new one; update `DATASET_DIGEST` in the same commit and say why.
//! Does NOT prove anything about COLMAP's path (see `walk_to_model.rs`) or real frames.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use s3tir_calib::model::colmap::read_model;
use s3tir_capture::tools::Digest;
use s3tir_tests::{bin, read_walk_truth, run_ok, thermal_sequence};
use serde_json::Value;

/// FNV-1a of the dataset's files (`dataset_digest`), as written when the session was committed.
const DATASET_DIGEST: &str = "0ba8803268a2168a";

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/sim_walk_tags")
        .join(name)
}

/// Digest of what the trainer reads: every image (name and bytes), the model's three text
/// files and `holdout.txt`, in name order. `poses.json` is left out: it records timings.
fn dataset_digest(ds: &Path) -> String {
    let mut d = Digest::default();
    let mut files: Vec<PathBuf> = std::fs::read_dir(ds.join("images"))
        .expect("images/")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        files.push(ds.join("sparse/0").join(f));
    }
    files.push(ds.join("holdout.txt"));
    for f in &files {
        let name = f.strip_prefix(ds).expect("inside the dataset");
        d.update(name.to_string_lossy().as_bytes());
        d.update(&std::fs::read(f).unwrap_or_else(|e| panic!("{}: {e}", f.display())));
    }
    d.hex()
}

#[test]
fn the_committed_walk_replays_into_the_same_dataset_and_trains() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let session = data("walk.mcap");
    let tags = data("tags.toml");

    // 1. capture's export runs the poses stage: the fast path, no COLMAP needed.
    let ds = tmp.path().join("dataset");
    run_ok(
        Command::new(bin("s3tir-capture"))
            .arg("export")
            .arg(&session)
            .arg("--dataset")
            .arg(&ds)
            .arg("--tags")
            .arg(&tags)
            // No COLMAP on this path: a missing program must not matter.
            .env("S3TIR_COLMAP", "/nonexistent/colmap"),
        "s3tir-capture export --dataset --tags",
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(ds.join("poses.json")).expect("poses.json"))
            .expect("poses.json is JSON");
    assert_eq!(report["pose_source"], "apriltags", "{report}");
    let digest = dataset_digest(&ds);
    assert_eq!(
        digest, DATASET_DIGEST,
        "the committed walk no longer replays into the pinned dataset (new digest {digest}); if the change is intended, update DATASET_DIGEST and say why"
    );

    // 2. The poses are the truth's, in metres.
    let truth = read_walk_truth(&data("truth.json"));
    let model = read_model(&ds.join("sparse/0")).expect("the dataset's model");
    let mut rot: Vec<f64> = Vec::new();
    let mut centre: Vec<f64> = Vec::new();
    for im in &model.images {
        let seq = thermal_sequence(&im.name);
        let (e, t) = (im.cam_from_world.inverse(), truth.thermal[&seq]);
        rot.push(e.rotation.angle_between(t.rotation).to_degrees());
        centre.push((e.translation_m - t.translation_m).length());
    }
    rot.sort_by(f64::total_cmp);
    centre.sort_by(f64::total_cmp);
    let (r, c) = (rot[rot.len() / 2], centre[centre.len() / 2]);
    eprintln!(
        "replay: {} views, median rotation {r:.3}°, centre {c:.4} m; digest {digest}",
        model.images.len()
    );
    assert!(model.images.len() >= 5, "views: {}", model.images.len());
    assert!(r < 0.5, "median rotation error {r:.3}° (< 0.5°)");
    assert!(
        c < 0.01 * truth.extent_m,
        "median centre error {c:.4} m (< 1 % of {:.2} m)",
        truth.extent_m
    );

    // 3. s3tir-train SESSION.mcap: the same dataset, then 200 steps.
    let run_dir = tmp.path().join("run");
    run_ok(
        Command::new(bin("s3tir-train"))
            .arg(&session)
            .arg("--tags")
            .arg(&tags)
            .arg("--out")
            .arg(&run_dir)
            .args([
                "--iters",
                "200",
                "--warmup",
                "100",
                "--budget",
                "1000",
                "--backend",
                "cpu",
            ])
            .args(["--beta-lr", "0.05", "--seed", "1"])
            .args(["--eval-every-s", "1e9", "--checkpoint-every-s", "1e9"])
            .env("S3TIR_COLMAP", "/nonexistent/colmap"),
        "s3tir-train SESSION.mcap --tags",
    );
    assert_eq!(
        dataset_digest(&tmp.path().join("run-dataset")),
        digest,
        "s3tir-train SESSION.mcap must pose the session exactly as export --dataset does"
    );
    let text = run_ok(
        Command::new(bin("s3tir-train"))
            .args(["eval", "--json"])
            .arg(&run_dir),
        "s3tir-train eval",
    );
    let v: Value = serde_json::from_str(&text).expect("eval --json");
    let psnr = v["psnr"].as_f64().unwrap_or(f64::NAN);
    eprintln!("replay: held-out PSNR after 200 steps {psnr:.2} dB");
    assert!(
        psnr.is_finite() && psnr > 15.0,
        "held-out PSNR {psnr} dB after 200 steps on the replayed walk (> 15 dB expected)"
    );
}
