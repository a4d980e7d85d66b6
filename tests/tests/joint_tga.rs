//! TGA-GS (joint thermal + RGB training) on the simulated joint scene, end to end through the
//! real binaries:
//! `s3tir-firmware-sim scene --rgb-scale 4 --low-light` writes a joint RGB + thermal dataset
//! with high-resolution truth (a Lepton-like thermal camera at W×H, a low-light RGB camera at
//! 4W×4H, 3 cm apart), the trainer reads both image sets of it, and `s3tir-train ablation`
//! trains the four TGA-GS variants (thermal-only, joint, joint without the thermal gradient
//! alignment loss, joint without RGB pre-training) at equal iterations on the CPU backend,
//! then at equal training time (thermal-only trained again for the joint run's time), each
//! scored against the truth; `eval --truth` reads a run back.
//!
//! Proves: the joint model beats the thermal-only model on thermal rendered at the RGB
//! resolution (PSNR against the super-resolved truth), at equal iterations and at equal time,
//! and on depth error at the RGB cameras at equal iterations;
//! the joint model's super-resolved thermal beats bicubic upsampling of the recorded thermal
//! image on the same held-out views (the render alone in PSNR; fused with the recorded image
//! by back-projection, `renders_sr_fused/`, in PSNR, SSIM and kelvin MAE); the colour head exists only in runs with RGB views; the
//! run folders hold what a user reads (`renders_sr/` and `renders_sr_fused/` at 4×,
//! `rgb_background.json`) and
//! `eval --truth` reproduces the table's figures from the files.
//!
//! The ablation also meshes each variant (`s3tir-train mesh`'s pipeline, through the same
//! cameras) and scores the mesh against the scene's truth surface; this test holds the scores
//! within the spread measured over two seeds (no ordering between variants).
//!
//! Does NOT prove: anything on real data (sun-board's real pairs are posed and trained jointly
//! in `folder_sun_board.rs`; at equal time there the joint model does not yet beat thermal-only,
//! see trainer/README.md), that the thermal gradient alignment loss helps (the table reports it;
//! measured on the simulated scene only), nor the Vulkan backend (its parity tests).
//!
//! Needs the workspace's binaries (`make test` / `cargo test --workspace`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::Command;

use s3tir_tests::{bin, json_f64 as f, run_ok};
use s3tir_trainer::dataset::{Dataset, LoadOptions, Modality};
use serde_json::Value;

const WIDTH: u32 = 32;
const HEIGHT: u32 = 24;
const SCALE: u32 = 4;
const VIEWS: usize = 16;
const ITERS: &str = "800";
const WARMUP: &str = "200";
const BUDGET: &str = "3000";

/// The row of `variant` in the table that holds `equal` ("iterations" or "time") equal.
fn row<'a>(rows: &'a [Value], variant: &str, equal: &str) -> &'a Value {
    rows.iter()
        .find(|r| r["variant"] == variant && r["equal"] == equal)
        .unwrap_or_else(|| panic!("ablation.json has no {variant} row at equal {equal}"))
}

fn score<'a>(rows: &'a [Value], variant: &str) -> &'a Value {
    &row(rows, variant, "iterations")["score"]
}

#[test]
fn joint_rgb_thermal_beats_thermal_only_at_the_rgb_resolution_and_on_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    run_ok(
        Command::new(bin("s3tir-firmware-sim")).args([
            "scene",
            "--out",
            data.to_str().unwrap(),
            "--rgb-scale",
            &SCALE.to_string(),
            "--width",
            &WIDTH.to_string(),
            "--height",
            &HEIGHT.to_string(),
            "--views",
            &VIEWS.to_string(),
            "--low-light",
            "--seed",
            "1",
        ]),
        "s3tir-firmware-sim scene --rgb-scale",
    );

    // The trainer reads both image sets, each through its own camera, or one of them.
    let both = Dataset::load(&data, &LoadOptions::default()).unwrap();
    assert_eq!(
        both.views.len(),
        2 * VIEWS,
        "one thermal and one RGB image per instant"
    );
    let rgb = both.views.iter().filter(|v| v.rgb.is_some()).count();
    assert_eq!(rgb, VIEWS, "the RGB images read as RGB");
    for v in &both.views {
        let (w, h) = if v.rgb.is_some() {
            (SCALE * WIDTH, SCALE * HEIGHT)
        } else {
            (WIDTH, HEIGHT)
        };
        assert_eq!(
            (v.camera.width, v.camera.height),
            (w as usize, h as usize),
            "{} is seen through its own camera",
            v.name
        );
    }
    assert_eq!(
        both.test.len(),
        4,
        "holdout.txt holds out instants 0 and 8 in both modalities"
    );
    for (m, n) in [(Modality::Thermal, VIEWS), (Modality::Rgb, VIEWS)] {
        let d = Dataset::load(
            &data,
            &LoadOptions {
                modality: m,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(d.views.len(), n, "--views {m} keeps one image set");
        assert_eq!(d.test.len(), 2, "--views {m} keeps its held-out views");
    }

    let out = tmp.path().join("ablation");
    let started = std::time::Instant::now();
    let text = run_ok(
        Command::new(bin("s3tir-train")).args([
            "ablation",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--iters",
            ITERS,
            "--warmup",
            WARMUP,
            "--budget",
            BUDGET,
            "--seed",
            "1",
            "--eval-every-s",
            "1e9",
            "--checkpoint-every-s",
            "1e9",
            // The bounds below were measured on the CPU reference.
            "--backend",
            "cpu",
        ]),
        "s3tir-train ablation",
    );
    println!("{text}(ablation: {:.0} s)", started.elapsed().as_secs_f64());
    let rows: Vec<Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("ablation.json")).unwrap()).unwrap();
    assert_eq!(
        rows.len(),
        8,
        "four variants at equal iterations and four at equal time in ablation.json"
    );
    // The scene has a truth surface: every variant is meshed and scored (the mesh columns of
    // the ablation). No ordering is asserted: at this size the variants' meshes differ by less
    // than their run-to-run spread. The bounds are the measured spread widened by that spread
    // once more: this ablation (these settings, CPU backend) with --seed 1 and --seed 2, all
    // four variants, gave Chamfer 0.030–0.040 m, F-score 0.35–0.47 and vertex MAE 3.15–4.01 K
    // (2026-11-29).
    for r in &rows {
        let m = &r["mesh"];
        assert!(
            f(m, &["chamfer_m"]) < 0.05 && f(m, &["f_score"]) > 0.25 && f(m, &["kelvin_mae"]) < 5.0,
            "{}'s mesh should match the truth surface as measured (Chamfer < 5 cm, F > 0.25, \
             vertex MAE < 5 K), got {m}",
            r["variant"]
        );
    }
    assert!(out.join("ablation.md").is_file(), "the table is written");
    let thermal = score(&rows, "thermal-only");
    let joint = score(&rows, "joint");

    let sr = |s: &Value| f(s, &["thermal_sr", "psnr"]);
    assert!(
        sr(joint) > sr(thermal),
        "joint thermal at {SCALE}× ({:.2} dB) should beat thermal-only ({:.2} dB)",
        sr(joint),
        sr(thermal)
    );
    let depth = |s: &Value| f(s, &["depth_rgb", "mae_m"]);
    assert!(
        depth(joint) < depth(thermal),
        "joint depth error at the RGB cameras ({:.1} mm) should be below thermal-only's \
         ({:.1} mm)",
        1000.0 * depth(joint),
        1000.0 * depth(thermal)
    );
    let cover = |s: &Value| f(s, &["depth_rgb", "coverage"]);
    assert!(
        cover(joint) >= cover(thermal) - 0.05,
        "the joint depth figure covers as much of the surface ({:.2} vs {:.2})",
        cover(joint),
        cover(thermal)
    );
    let bicubic = f(joint, &["bicubic_sr", "psnr"]);
    assert!(
        sr(joint) > bicubic,
        "super-resolved thermal ({:.2} dB) should beat bicubic upsampling ({bicubic:.2} dB)",
        sr(joint)
    );
    // Fused with the recorded image (back-projection), on every figure: PSNR, SSIM, kelvin MAE,
    // against bicubic and against the fusion's own control — the same back-projection started
    // from bicubic, which the recorded image alone gives (+0.6 dB over bicubic by itself): what
    // is left is the model's contribution. The demo's joint run (`make demo`, 2026-11-29):
    // fused 27.19 dB / 0.910 / 0.783 K, control 25.18 dB / 0.876 / 0.994 K, bicubic 24.53 dB.
    for (what, better) in [("psnr", 1.0), ("ssim", 1.0), ("kelvin_mae", -1.0)] {
        let fused = f(joint, &["fused_sr", what]);
        for control in ["bicubic_sr", "bicubic_bp_sr"] {
            let c = f(joint, &[control, what]);
            assert!(
                better * (fused - c) > 0.0,
                "the joint model's render fused with the recorded image should beat \
                 {control} on {what}: {fused:.4} vs {c:.4}"
            );
        }
    }
    // At equal training time (the joint run's): thermal-only trains again with that budget
    // (a thermal step costs a quarter of a joint one here: ~3 300 iterations against 800) and
    // the joint model still renders the better thermal at 4× and fuses to the better SR.
    // Measured (2026-11-29, this test's settings, RGB pre-training 200 by default): joint
    // 25.98 dB at 4×, fused 27.24 dB; thermal-only at equal time 25.15 dB, fused 26.58 dB
    // (3 351 iterations in 94 s). Depth is not asserted at equal time: both cover 97 % of the
    // surface and the joint error is lower by only 2.6 mm (101.6 vs 104.2 mm).
    let joint_t = row(&rows, "joint", "time");
    assert_eq!(
        joint_t["run_dir"],
        row(&rows, "joint", "iterations")["run_dir"],
        "the joint run is the equal-time reference: the same run in both tables"
    );
    let thermal_t = row(&rows, "thermal-only", "time");
    let (t_ref, t_th) = (
        f(joint_t, &["train_seconds"]),
        f(thermal_t, &["train_seconds"]),
    );
    assert!(
        thermal_t["run_dir"]
            .as_str()
            .unwrap()
            .ends_with("thermal-only-equal-time")
            && (t_th - t_ref).abs() <= 0.1 * t_ref
            && f(thermal_t, &["iterations"])
                > 2.0 * f(row(&rows, "thermal-only", "iterations"), &["iterations"]),
        "thermal-only is trained again for the joint run's {t_ref:.0} s (more iterations): \
         {thermal_t}"
    );
    let (joint_t, thermal_t) = (&joint_t["score"], &thermal_t["score"]);
    for what in ["thermal_sr", "fused_sr"] {
        let (j, t) = (f(joint_t, &[what, "psnr"]), f(thermal_t, &[what, "psnr"]));
        assert!(
            j > t,
            "at equal time the joint model's {what} ({j:.2} dB) should beat thermal-only's \
             ({t:.2} dB)"
        );
    }
    assert!(
        thermal["rgb_psnr"].is_null() && joint["rgb_psnr"].as_f64().is_some(),
        "only runs with RGB views have a colour head: {} / {}",
        thermal["rgb_psnr"],
        joint["rgb_psnr"]
    );

    // What a user reads in a joint run folder, and `eval --truth` from the files.
    let run = out.join("joint");
    check_sr_render(&run.join("renders_sr").join("thermal_0000.png"));
    check_sr_render(&run.join("renders_sr_fused").join("thermal_0000.png"));
    assert!(
        run.join("rgb_background.json").is_file(),
        "the learned RGB background is written"
    );
    // The SR render scored against the recorded held-out frames themselves (what a real set
    // without high-resolution truth can say): averaged back to the recorded resolution it
    // agrees with them as the native render does (measured: 32.34 dB vs 31.70 dB native, seed 2).
    let eval: Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval.json")).unwrap()).unwrap();
    let sc = &eval["sr_consistency"];
    assert_eq!(
        sc["scale"], SCALE,
        "eval.json scores the {SCALE}× render: {sc}"
    );
    let (down, native) = (f(sc, &["psnr"]), f(&eval, &["psnr"]));
    assert!(
        (down - native).abs() < 1.5 && f(sc, &["ssim"]) > 0.9,
        "the {SCALE}× render averaged to the recorded resolution ({down:.2} dB, {sc}) should \
         match the recorded frames as the native render does ({native:.2} dB)"
    );
    let json = run_ok(
        Command::new(bin("s3tir-train")).args(["eval", run.to_str().unwrap(), "--truth", "--json"]),
        "s3tir-train eval --truth",
    );
    let again: Value = serde_json::from_str(&json).unwrap();
    for path in [
        &["thermal_sr", "psnr"][..],
        &["fused_sr", "kelvin_mae"],
        &["depth_rgb", "mae_m"],
        &["rgb_psnr"],
    ] {
        let (a, b) = (f(&again, path), f(joint, path));
        assert!(
            (a - b).abs() <= 1e-3 * b.abs().max(1.0),
            "eval --truth {} = {a} should reproduce the table's {b} from the run folder",
            path.join(".")
        );
    }
}

fn check_sr_render(path: &Path) {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("super-resolved render {}: {e}", path.display()))
        .into_luma16();
    assert_eq!(
        (img.width(), img.height()),
        (SCALE * WIDTH, SCALE * HEIGHT),
        "{} is at the RGB resolution",
        path.display()
    );
}
