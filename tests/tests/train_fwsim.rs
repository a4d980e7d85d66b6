//! Issue 7's first "Done when", end to end through the real binaries on the simulated rig's own
//! scene: `s3tir-firmware-sim scene` (a box with a sharp painted/bare-metal emissivity edge, a
//! heated pipe of 15 cm radius, an underfloor heating pipe warming a smooth stripe of the floor,
//! a finned radiator), then `s3tir-train` in s3tir mode and in 3dgs mode at equal iterations,
//! budget and seed on the CPU backend, then `s3tir-train eval --json` on both runs; the Ψ_β
//! G-buffer is read from the exact `gbuffers/<view>_psi_beta.npy` the trainer writes for each
//! held-out view, with pixel masks from the scene's ground-truth geometry (`scene::pixel_hits`):
//! the box edge is every box pixel whose surface point lies within 3 cm of the painted/bare
//! boundary; the pipe's interior every pipe-side pixel whose 5×5 neighbourhood is all pipe side
//! (2 px clear of its outline, itself a sharp edge); the floor stripe every floor pixel within
//! 6 cm of the underfloor pipe's line whose 5×5 neighbourhood is all floor.
//!
//! Proves (CI test): s3tir has the higher held-out PSNR and the lower held-out kelvin MAE, the
//! 3dgs run's Ψ_β is 2 everywhere, and the masks hold enough pixels; it prints every Ψ_β figure.
//! Takes ~50 s in the dev profile on a loaded 2-core machine (s3tir ~30 s, 3dgs ~16 s).
//!
//! Does NOT prove (the `#[ignore]`d test keeps the Ψ_β bounds and fails today): that Ψ_β
//! is high on the edge and ≈ 2 on the smooth pipe; nor anything at the paper's scale (30 000
//! iterations, real data), or that the Vulkan backend agrees (its parity tests do that).
//!
//! Why the Ψ_β criterion fails on this scene (study of 2026-11-21; every run is the s3tir run
//! below — 64×48, 16 views, 400 iterations, warm-up 100, budget 300, β lr 0.05, consistency
//! every 4, seed 1 — on the release build, with one change; masks as below, raw Ψ_β; reproduce
//! with `cargo run -p s3tir-tests --example fwsim_psi_beta -- RUN_DIR 64 48 16`):
//!
//! | run                                | PSNR dB / MAE K | edge  | pipe  | stripe | rest of box |
//! |------------------------------------|-----------------|-------|-------|--------|-------------|
//! | as below                           | 27.66 / 0.879   | 3.435 | 4.073 | 3.185  | 3.566       |
//! | `--beta-lr 1e-7` (β held ≈ 2)      | 26.47 / 1.073   | 2.000 | 2.000 | 2.000  | 2.000       |
//! | `--no-smooth`                      | 27.70 / 0.861   | 3.794 | 4.597 | 3.277  | 4.257       |
//! | `--no-consist`                     | 27.68 / 0.878   | 3.433 | 4.116 | 3.187  | 3.595       |
//! | `--mode ges` (no bands)            | 25.07 / 1.280   | 4.083 | 4.441 | 4.559  | 4.121       |
//! | 128×96 images                      | 26.75 / 0.906   | 4.101 | 4.477 | 3.342  | 4.382       |
//! | + shape prior λb 0.003 (see below) | 27.58 / 0.891   | 2.897 | 3.449 | 2.528  | 2.966       |
//! | + shape prior λb 0.01              | 27.19 / 0.967   | 2.437 | 2.729 | 2.051  | 2.426       |
//! | + shape prior λb 0.03              | 26.75 / 1.031   | 2.105 | 2.094 | 2.000  | 2.101       |
//! | + shape prior λb 0.1               | 26.50 / 1.070   | 2.004 | 2.000 | 2.000  | 2.001       |
//! | + λb 0.01, budget 1000             | 29.30 / 0.719   | 2.158 | 2.382 | 2.025  | 2.146       |
//! | + λb 0.01, 128×96                  | 26.30 / 0.997   | 2.660 | 2.782 | 2.136  | 2.766       |
//! | `--mode 3dgs`                      | 23.90 / 1.539   | 2     | 2     | 2      | 2           |
//!
//! - β does not mark the emissivity edge here: the primitives centred within 3 cm of it have
//!   the *lowest* β of the box (median 2.90, against 3.59 on the painted half and 3.07 on the
//!   bare half; 2.03 / 4.55 / 3.26 at 128×96). β rises on bright objects against the dark
//!   floor and background — pipe hot third 4.20, middle 3.46, cool 3.50; radiator 4.28;
//!   floor 2.94, but the floor stripe, brighter than the rest of the floor and far from any
//!   outline, 2.64 — i.e. along high-contrast silhouettes. The pipe's outline is the sharpest
//!   edge in the scene (21–25 K/px in the target images, against 10.5–12 K/px across the
//!   emissivity edge and 8.5–12.5 K/px on the box outline).
//! - "Pipe interior" is not away from that outline: at 64×48 every pixel of the mask is within
//!   5.4 px of it, and the pipe's primitives (median largest scale 0.17 m ≈ 5.5 px; 11 px at
//!   128×96) span the pipe's whole 0.3 m diameter, so every pipe primitive is a silhouette
//!   primitive. Over all held-out pixels, Ψ_β within 5 px of a sharp edge (|∇T| > 2 K/px) is
//!   3.63–3.82 and ≥ 6 px away 3.18–3.22 (those are mostly floor: dim as well as far from
//!   edges, so this alone does not separate brightness from edges).
//! - The training settings are not the difference, the scene is: the trainer's analytic scene
//!   (`s3tir-train synth DIR --width 48 --height 36`: a wall filling every view, an emissivity
//!   step and a pipe's warm band *inside* the wall, no silhouettes) trained with exactly the
//!   settings below (no density control, budget 300, β lr 0.05) meets the bounds: edge 3.765,
//!   pipe 2.186 (37.64 dB); and still does with this scene's sensor effects imitated (its
//!   images blurred with σ 0.54 px and 0.05 K noise added): edge 3.162, pipe 2.136. There β
//!   and the band amplitudes concentrate on the primitives within 10 cm of the step (median β
//!   3.1–4.4, largest band amplitude 0.16–0.21, against β 2.4 and 0.02 beyond 40 cm): the
//!   paper's mechanism (§3, Fig. 3). Here the largest band amplitude is 0.12–0.19 on every
//!   surface, the edge's primitives included.
//! - Higher resolution does not help because the primitives do not shrink: the CLI's density
//!   control starts at iteration 500 (the default), so a 400-iteration run never densifies,
//!   and the budget is full from the initial subsample anyway.
//! - Adam normalises steps, so β drifts wherever its gradient is small but consistent. A
//!   rendered shape-sparsity prior `λb·mean(Ψ_β − 2·alpha)` (tried, not kept) holds β at 2
//!   where the data pay less than λb per unit of coverage: it brings the stripe and the pixels
//!   far from edges to ≈ 2 (λb 0.01: 2.08–2.10 ≥ 6 px from an edge, 2.43–2.55 within 5 px) but
//!   shrinks β everywhere alike — the pipe stays above the edge and no λb gives an edge more
//!   than 0.5 above both smooth regions. With β held at 2 (`--beta-lr 1e-7`) the Adam second
//!   moments show why: the edge's primitives get the smallest β gradient (median √v 3.2e-6,
//!   box 9.1e-6, pipe 3.1e-5, radiator 3.5e-5, in β units).
//! - The TV term lowers β everywhere (`--no-smooth` raises it by 0.1–0.7); the consistency term
//!   changes nothing measurable. Raw Ψ_β also understates β where alpha < 1: divided by alpha
//!   (as `pipeline_modes.rs` does) the three masks read 4.14 / 4.15 / 4.18.
//!
//! Earlier measurements (previous session): longer runs (1 200 iterations), a longer warm-up,
//! faster opacity/scale learning, a higher initial opacity, pure L1 (no D-SSIM) or no
//! regularisers change the figures but not the ordering.
//! Needs the workspace's binaries (`make test` / `cargo test --workspace`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::Command;

use s3tir_firmware_sim::scene::{self, BOX_C, FLOOR_PIPE_X, SceneObject};
use s3tir_tests::bin;
use s3tir_trainer::report::read_npy_f32;
use serde_json::Value;

const VIEWS: usize = 16;
const WIDTH: u32 = 64;
const HEIGHT: u32 = 48;
const ITERS: &str = "400";
const WARMUP: &str = "100";
const BUDGET: &str = "300";
const BETA_LR: &str = "0.05";
const CONSIST_EVERY: &str = "4";
const SEED: &str = "1";

/// Ψ_β bounds (as the trainer's analytic-scene test `pipeline_modes.rs`).
const PIPE_BETA_MAX: f64 = 2.3;
const EDGE_BETA_MIN: f64 = 2.75;
const EDGE_OVER_PIPE_MIN: f64 = 0.5;
/// Box pixels within this distance of the emissivity boundary (x = `BOX_C.x`) are "edge".
const EDGE_HALF_WIDTH_M: f64 = 0.03;
/// Floor pixels within this distance of the underfloor pipe's line are "stripe".
const STRIPE_HALF_WIDTH_M: f64 = 0.06;
/// Interior masks: every pixel within this many pixels is the same surface.
const ERODE_PX: i64 = 2;

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn train(data: &Path, run_dir: &Path, mode: &str) -> Value {
    run(Command::new(bin("s3tir-train")).args([
        data.to_str().unwrap(),
        "--out",
        run_dir.to_str().unwrap(),
        "--mode",
        mode,
        "--iters",
        ITERS,
        "--warmup",
        WARMUP,
        "--budget",
        BUDGET,
        "--beta-lr",
        BETA_LR,
        "--consist-every",
        CONSIST_EVERY,
        "--seed",
        SEED,
        "--eval-every-s",
        "1e9",
        "--checkpoint-every-s",
        "1e9",
    ]));
    let json =
        run(Command::new(bin("s3tir-train")).args(["eval", run_dir.to_str().unwrap(), "--json"]));
    serde_json::from_str(&json).unwrap()
}

/// What one pipeline run measured.
struct Figures {
    psnr_s3: f64,
    psnr_gs: f64,
    mae_s3: f64,
    mae_gs: f64,
    /// Ψ_β per mask over the held-out views of the s3tir run, as (mean, pixels).
    edge: (f64, usize),
    pipe: (f64, usize),
    stripe: (f64, usize),
    /// Range of the 3dgs run's Ψ_β where alpha > 0.5.
    gs_range: (f32, f32),
}

fn mean(v: &[f32]) -> (f64, usize) {
    let s: f64 = v.iter().map(|&x| f64::from(x)).sum();
    (s / v.len().max(1) as f64, v.len())
}

/// Scene, both trainings, both evaluations and the Ψ_β figures.
fn pipeline() -> Figures {
    let t0 = std::time::Instant::now();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    run(Command::new(bin("s3tir-firmware-sim")).args([
        "scene",
        "--out",
        data.to_str().unwrap(),
        "--views",
        &VIEWS.to_string(),
        "--width",
        &WIDTH.to_string(),
        "--height",
        &HEIGHT.to_string(),
        "--seed",
        SEED,
    ]));
    let s3 = train(&data, &tmp.path().join("s3tir"), "s3tir");
    let gs = train(&data, &tmp.path().join("3dgs"), "3dgs");
    let num = |v: &Value, k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k} in {v}"));

    let cam = scene::scene_camera(WIDTH, HEIGHT);
    let poses = scene::orbit(VIEWS);
    let (w, h) = (WIDTH as usize, HEIGHT as usize);
    let (mut edge_v, mut pipe_v, mut stripe_v, mut gs_v) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let views = s3["views"].as_array().unwrap();
    assert!(!views.is_empty(), "no held-out views in {s3}");
    for view in views {
        let name = view["name"].as_str().unwrap();
        let stem = name.trim_end_matches(".png");
        let k: usize = stem.parse().unwrap();
        let hits = scene::pixel_hits(&cam, &poses[k]);
        let object_at = |x: i64, y: i64| {
            (x >= 0 && y >= 0 && x < w as i64 && y < h as i64)
                .then(|| hits[y as usize * w + x as usize].map(|(o, _)| o))
                .flatten()
        };
        let interior = |x: usize, y: usize, obj: SceneObject| {
            (-ERODE_PX..=ERODE_PX).all(|dy| {
                (-ERODE_PX..=ERODE_PX)
                    .all(|dx| object_at(x as i64 + dx, y as i64 + dy) == Some(obj))
            })
        };
        let gb = tmp.path().join("s3tir/gbuffers");
        let (bw, bh, beta) = read_npy_f32(&gb.join(format!("{stem}_psi_beta.npy"))).unwrap();
        let (_, _, alpha) = read_npy_f32(&gb.join(format!("{stem}_alpha.npy"))).unwrap();
        assert_eq!((bw, bh), (w, h), "G-buffer size of view {stem}");
        let (mut e, mut p, mut s) = (Vec::new(), Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if alpha[i] <= 0.5 {
                    continue;
                }
                match hits[i] {
                    Some((SceneObject::Box, pt)) if (pt.x - BOX_C.x).abs() < EDGE_HALF_WIDTH_M => {
                        e.push(beta[i]);
                    }
                    Some((SceneObject::PipeSide, _)) if interior(x, y, SceneObject::PipeSide) => {
                        p.push(beta[i]);
                    }
                    Some((SceneObject::Ground, pt))
                        if (pt.x - FLOOR_PIPE_X).abs() < STRIPE_HALF_WIDTH_M
                            && interior(x, y, SceneObject::Ground) =>
                    {
                        s.push(beta[i]);
                    }
                    _ => {}
                }
            }
        }
        eprintln!(
            "view {stem}: Ψ_β box edge {:.3} ({} px), pipe interior {:.3} ({} px), floor stripe \
             {:.3} ({} px)",
            mean(&e).0,
            e.len(),
            mean(&p).0,
            p.len(),
            mean(&s).0,
            s.len()
        );
        edge_v.extend(e);
        pipe_v.extend(p);
        stripe_v.extend(s);
        let gb3 = tmp.path().join("3dgs/gbuffers");
        let (_, _, beta3) = read_npy_f32(&gb3.join(format!("{stem}_psi_beta.npy"))).unwrap();
        let (_, _, alpha3) = read_npy_f32(&gb3.join(format!("{stem}_alpha.npy"))).unwrap();
        gs_v.extend((0..w * h).filter(|&i| alpha3[i] > 0.5).map(|i| beta3[i]));
    }
    let f = Figures {
        psnr_s3: num(&s3, "psnr"),
        psnr_gs: num(&gs, "psnr"),
        mae_s3: num(&s3, "kelvin_mae"),
        mae_gs: num(&gs, "kelvin_mae"),
        edge: mean(&edge_v),
        pipe: mean(&pipe_v),
        stripe: mean(&stripe_v),
        gs_range: (
            gs_v.iter().copied().fold(f32::INFINITY, f32::min),
            gs_v.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        ),
    };
    eprintln!(
        "held out: s3tir {:.2} dB, {:.3} K ({} primitives); 3dgs {:.2} dB, {:.3} K ({} \
         primitives). Ψ_β: box edge {:.3} ({} px), pipe interior {:.3} ({} px), floor stripe \
         {:.3} ({} px); 3dgs Ψ_β in [{}, {}]. {:.1} s in all",
        f.psnr_s3,
        f.mae_s3,
        s3["primitives"],
        f.psnr_gs,
        f.mae_gs,
        gs["primitives"],
        f.edge.0,
        f.edge.1,
        f.pipe.0,
        f.pipe.1,
        f.stripe.0,
        f.stripe.1,
        f.gs_range.0,
        f.gs_range.1,
        t0.elapsed().as_secs_f64()
    );
    f
}

#[test]
fn s3tir_beats_3dgs_on_the_firmware_sim_scene() {
    let f = pipeline();
    assert!(
        f.psnr_s3 > f.psnr_gs,
        "held-out PSNR: s3tir {:.2} dB should exceed 3dgs {:.2} dB",
        f.psnr_s3,
        f.psnr_gs
    );
    assert!(
        f.mae_s3 < f.mae_gs,
        "held-out kelvin MAE: s3tir {:.3} K should be below 3dgs {:.3} K",
        f.mae_s3,
        f.mae_gs
    );
    assert!(
        (f.gs_range.0 - 2.0).abs() < 1e-3 && (f.gs_range.1 - 2.0).abs() < 1e-3,
        "3dgs mode must render Ψ_β = 2 everywhere, got [{}, {}]",
        f.gs_range.0,
        f.gs_range.1
    );
    // The edge is a 6 cm band seen obliquely in the held-out views and counted only where the
    // trained model covers it (alpha > 0.5): 49 px (5 + 44) with this commit's simulator.
    assert!(
        f.edge.1 >= 8 && f.pipe.1 >= 100 && f.stripe.1 >= 20,
        "masks too small: {} edge px, {} pipe-interior px, {} stripe px",
        f.edge.1,
        f.pipe.1,
        f.stripe.1
    );
}

/// The Ψ_β criterion on the same runs; fails today (see the module docs for the
/// figures and the diagnosis). Run with `--ignored --nocapture`.
#[test]
#[ignore = "Ψ_β criterion not met: β follows silhouettes, not the emissivity edge (module docs)"]
fn psi_beta_is_high_on_the_edge_and_two_on_the_smooth_pipes() {
    let f = pipeline();
    let (edge, pipe, stripe) = (f.edge.0, f.pipe.0, f.stripe.0);
    assert!(
        pipe < PIPE_BETA_MAX && stripe < PIPE_BETA_MAX,
        "Ψ_β should stay ≈ 2 (< {PIPE_BETA_MAX}) on the pipe interior ({pipe:.3}) and on the \
         floor stripe ({stripe:.3}); edge {edge:.3}"
    );
    assert!(
        edge > EDGE_BETA_MIN && edge > pipe.max(stripe) + EDGE_OVER_PIPE_MIN,
        "Ψ_β on the box's emissivity edge ({edge:.3}) should exceed {EDGE_BETA_MIN} and the \
         smooth regions' (pipe {pipe:.3}, stripe {stripe:.3}) by > {EDGE_OVER_PIPE_MIN}"
    );
}
