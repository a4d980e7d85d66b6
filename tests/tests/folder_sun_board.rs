//! A real folder of thermal + RGB pairs to a joint training run, through the real binaries, on
//! sun-board (47 pairs of a sun-heated board from a DJI dual camera, no metadata; thermal/
//! and rgb/ paired by name):
//! 1. `s3tir-calib DIR --out cal.yaml` calibrates both cameras and the extrinsic from the
//!    folder (DIR/board.toml: 6 × 5 inner corners, 100 mm squares);
//! 2. `s3tir-calib poses DIR --board … --calibration … --with-rgb` poses every thermal shot by
//!    PnP on the board (at least the 32 views the Python script it replaced posed,
//!    every PnP within the stage's 2 px, cameras above the board) and every RGB partner by PnP
//!    in its own image, each RGB camera within centimetres of its thermal camera (a dual
//!    camera's lenses; a wrong 180° order would put it a metre away);
//! 3. the trainer reads the joint dataset — both image sets, each through its own camera, the
//!    held-out instants held out in both — and `s3tir-train` trains on it jointly, its
//!    held-out PSNR rising.
//!
//! Does NOT prove: that joint training helps on this set (a flat board on grass; the TGA-GS
//! figures are the ablation's, on the simulator), nor anything about GPS-posed folders
//! (calib/tests/folder_poses.rs, on thermal-facade).
//!
//! Needs the workspace's binaries (`make test` / `cargo test --workspace`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;

use s3tir_tests::{bin, run_ok, shared_data};
use s3tir_trainer::dataset::{Dataset, LoadOptions, Modality};
use serde_json::Value;

#[test]
fn sun_board_folder_is_posed_with_its_rgb_partners_and_trains_jointly() {
    let set = shared_data("sun-board");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("sun-board");
    std::fs::create_dir_all(&dir).unwrap();
    for sub in ["thermal", "rgb"] {
        std::os::unix::fs::symlink(set.join(sub), dir.join(sub)).unwrap();
    }
    let board = dir.join("board.toml");
    std::fs::write(
        &board,
        "[board]\ninner_corners = [6, 5]\nsquare_mm = 100.0\n",
    )
    .unwrap();
    let cal = tmp.path().join("cal/calibration.yaml");
    run_ok(
        Command::new(bin("s3tir-calib"))
            .arg(&dir)
            .arg("--out")
            .arg(&cal),
        "s3tir-calib DIR (calibrating sun-board)",
    );

    let data = tmp.path().join("ds");
    let text = run_ok(
        Command::new(bin("s3tir-calib"))
            .arg("poses")
            .arg(&dir)
            .arg("--board")
            .arg(&board)
            .arg("--calibration")
            .arg(&cal)
            .arg("--with-rgb")
            .args(["--max-points", "3000"])
            .arg("--out")
            .arg(&data)
            .arg("--json"),
        "s3tir-calib poses DIR --with-rgb",
    );
    let r: Value = serde_json::from_str(&text).unwrap();
    let (b, g) = (&r["board"], &r["rgb"]);
    eprintln!("sun-board: board {b}\nrgb {g}");
    assert_eq!(r["method"], "board");
    let posed = b["posed"].as_u64().unwrap();
    assert!(
        posed >= 32,
        "at least the script's 32 thermal views posed, got {posed}"
    );
    assert!(
        b["pnp_rms_px_max"].as_f64().unwrap() <= 2.0,
        "every thermal PnP within 2 px: {b}"
    );
    assert!(
        b["height_m"][0].as_f64().unwrap() > 0.3,
        "cameras above the board: {b}"
    );
    let rgb_views = g["views"].as_u64().unwrap();
    assert!(
        rgb_views >= 32 && g["from_board"].as_u64().unwrap() >= 32,
        "the RGB partners posed by PnP on the board: {g}"
    );
    let gap = g["centre_gap_m"][0].as_f64().unwrap();
    assert!(
        gap < 0.1,
        "each RGB camera within centimetres of its thermal camera (median {gap:.3} m): {g}"
    );

    let both = Dataset::load(&data, &LoadOptions::default()).unwrap();
    let rgb = both.views.iter().filter(|v| v.rgb.is_some()).count() as u64;
    let thermal = both.views.iter().filter(|v| v.thermal.is_some()).count() as u64;
    assert_eq!(
        (thermal, rgb),
        (posed, rgb_views),
        "the trainer reads every posed view of both modalities"
    );
    let rgb_cam = both.views.iter().find(|v| v.rgb.is_some()).unwrap().camera;
    assert_eq!(
        (rgb_cam.width, rgb_cam.height),
        (1014, 760),
        "RGB views through the RGB camera"
    );
    let held_rgb = both
        .test
        .iter()
        .filter(|&&i| both.views[i].rgb.is_some())
        .count() as u64;
    assert_eq!(
        held_rgb,
        g["held_out"].as_u64().unwrap(),
        "the partners of held-out thermal views are held out"
    );
    assert!(held_rgb > 0, "some views held out in both modalities");
    for m in [Modality::Thermal, Modality::Rgb] {
        let d = Dataset::load(
            &data,
            &LoadOptions {
                modality: m,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(!d.views.is_empty(), "--views {m} keeps its image set");
    }

    // A short run (3 000 seed points, a quarter of the resolution, 20 steps): it trains on
    // both sets and its held-out error falls.
    let run = tmp.path().join("run");
    let text = run_ok(
        Command::new(bin("s3tir-train"))
            .arg(&data)
            .arg("--out")
            .arg(&run)
            .args(["--iters", "20", "--downscale", "4", "--backend", "cpu"]),
        "s3tir-train on the joint folder dataset",
    );
    assert!(
        text.contains("joint RGB + thermal"),
        "the run is a joint one: {text}"
    );
    let metrics = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let psnr: Vec<f64> = metrics
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(3).unwrap().parse().unwrap())
        .collect();
    eprintln!("held-out PSNR over the run: {psnr:?}");
    let (first, last) = (psnr[0], psnr[psnr.len() - 1]);
    assert!(
        last > first + 1.0,
        "held-out PSNR rises by more than 1 dB in 20 steps: {first:.2} → {last:.2} dB"
    );
}
