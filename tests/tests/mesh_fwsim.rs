//! The thermal mesh (`s3tir-train mesh`) on the simulated scene, end to end through the real binaries:
//! `s3tir-firmware-sim scene` (objects layout: box, free-standing heated pipe, floor, radiator)
//! writes a thermal dataset and its truth surface (`truth/surface.ply`: the visible surface,
//! apparent kelvin per point); `s3tir-train` trains it on the CPU backend; `s3tir-train mesh
//! --truth` fuses the run's rendered depth and temperature into a mesh, scores it against the
//! truth, and writes the PLY files this test reads back.
//!
//! Proves: the mesh lies on the true surface (Chamfer distance, F-score at 2 cm) and carries
//! the right temperature (vertex kelvin MAE against the truth's apparent temperature); the
//! files are binary PLY with a float `kelvin` per vertex that our reader (the same one that
//! reads the simulator's truth) reads back with the counts the command reported; the
//! colour-mapped copy exists; the Vulkan backend's render of the same run gives the same mesh
//! within float noise; a mesh that cannot be made fails with a clear error and leaves the
//! existing file untouched.
//!
//! Does NOT prove: anything on real data (no real set has a known surface), watertightness
//! (the mesh is open where the views stop; the closed-sphere unit test covers the extraction),
//! nor the thermal gradient alignment loss's effect on the mesh (`joint_tga.rs` reports it).
//!
//! Thresholds are set from measurement (see the constants) with a margin for other seeds'
//! training noise. Needs the workspace's binaries (`make test` / `cargo test --workspace`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashSet;
use std::path::Path;
use std::process::Command;

use s3tir_tests::{bin, json_f64 as f, run_ok};
use s3tir_trainer::dataset::{Dataset, LoadOptions};
use s3tir_trainer::mesh::plyio::{read_mesh_ply, read_region};
use s3tir_trainer::mesh::score::score;
use s3tir_trainer::mesh::{Frame, Volume, extract};
use serde_json::Value;

const WIDTH: &str = "64";
const HEIGHT: &str = "48";
const VIEWS: &str = "16";
const ITERS: &str = "600";

fn mesh_json(run_dir: &Path, out: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        "mesh",
        run_dir.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--truth",
        "--json",
    ];
    args.extend_from_slice(extra);
    let text = run_ok(
        Command::new(bin("s3tir-train")).args(&args),
        "s3tir-train mesh",
    );
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("mesh --json printed {text}: {e}"))
}

/// A view as fused: camera, depth (metres, NaN: none), kelvin.
type Kept = (s3tir_trainer::camera::PinholeCamera, Vec<f32>, Vec<f32>);

fn frame(v: &Kept) -> Frame<'_> {
    Frame {
        camera: &v.0,
        depth_m: &v.1,
        kelvin: &v.2,
        rgb: None,
    }
}

fn write_scene(data: &Path) {
    run_ok(
        Command::new(bin("s3tir-firmware-sim")).args([
            "scene",
            "--out",
            data.to_str().unwrap(),
            "--width",
            WIDTH,
            "--height",
            HEIGHT,
            "--views",
            VIEWS,
            "--seed",
            "1",
        ]),
        "s3tir-firmware-sim scene",
    );
}

/// The fusion and extraction alone, fed the scene's true depth maps (`DATA/depth/`, every
/// view) instead of a model's renders: the mesh the stage makes when the geometry is right.
/// Measured (1 cm voxels, truncation 3 voxels, --min-weight 1, this scene): Chamfer 7.5 mm
/// (accuracy 7.3, completeness 7.7), F-score 0.930 at 2 cm (precision 0.896: 64 px views
/// give pixel footprints of ~2.7 cm at 1.6 m, coarser than the voxel; recall 0.966).
#[test]
fn true_depth_maps_fuse_into_the_true_surface() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    write_scene(&data);
    let d = Dataset::load(
        &data,
        &LoadOptions {
            holdout_every: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let views: Vec<Kept> = d
        .views
        .iter()
        .map(|v| {
            let img = image::open(data.join("depth").join(&v.name))
                .unwrap()
                .into_luma16();
            let depth: Vec<f32> = img
                .pixels()
                .map(|p| match p.0[0] {
                    0 => f32::NAN,
                    mm => f32::from(mm) / 1000.0,
                })
                .collect();
            let kelvin = vec![300.0f32; depth.len()];
            (v.camera, depth, kelvin)
        })
        .collect();
    let (voxel_m, trunc_m) = (0.01, 0.03);
    let mut keys = HashSet::new();
    for v in &views {
        Volume::touched_blocks(&frame(v), voxel_m, trunc_m, &mut keys);
    }
    let mut volume = Volume::new(voxel_m, trunc_m, false);
    volume.allocate(keys);
    for v in &views {
        volume.integrate(&frame(v));
    }
    let mesh = extract(&volume, 1.0);
    let truth = read_mesh_ply(&data.join("truth/surface.ply")).unwrap();
    let region = read_region(&data.join("truth/surface.ply")).unwrap();
    assert!(
        region.is_some(),
        "the truth surface should state its evaluation volume"
    );
    let s = score(&mesh, &truth, 0.02, region.as_ref());
    eprintln!("true depth fused: {s:?}");
    assert!(
        s.chamfer_m < 0.010,
        "true depth should fuse within 10 mm Chamfer distance of the truth surface, got {} m",
        s.chamfer_m
    );
    assert!(
        s.f_score > 0.9 && s.recall > 0.94,
        "true depth should fuse into F-score > 0.9 with recall > 0.94 at 2 cm, got F {} (recall {})",
        s.f_score,
        s.recall
    );
}

#[test]
fn mesh_of_a_trained_run_lies_on_the_true_surface_with_its_temperature() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    write_scene(&data);
    let truth = read_mesh_ply(&data.join("truth/surface.ply")).unwrap();
    assert!(
        truth.positions.len() > 1000,
        "the simulator's truth surface should hold thousands of points, has {}",
        truth.positions.len()
    );
    let run_dir = tmp.path().join("run");
    run_ok(
        Command::new(bin("s3tir-train")).args([
            data.to_str().unwrap(),
            "--out",
            run_dir.to_str().unwrap(),
            "--iters",
            ITERS,
            "--seed",
            "1",
            "--eval-every-s",
            "1e9",
            "--checkpoint-every-s",
            "1e9",
            // The mesh bounds below were measured on a model trained on the CPU reference.
            "--backend",
            "cpu",
        ]),
        "s3tir-train",
    );

    let out = tmp.path().join("mesh.ply");
    let s = mesh_json(&run_dir, &out, &[]);
    eprintln!("mesh summary: {s:#}");
    let (chamfer, f_score, kelvin_mae) = (
        f(&s, &["truth", "chamfer_m"]),
        f(&s, &["truth", "f_score"]),
        f(&s, &["truth", "kelvin_mae"]),
    );
    assert!(
        chamfer < CHAMFER_MAX_M,
        "the mesh should lie within {CHAMFER_MAX_M} m Chamfer distance of the true surface, is {chamfer} m"
    );
    assert!(
        f_score > F_SCORE_MIN,
        "F-score at 2 cm should exceed {F_SCORE_MIN}, is {f_score}"
    );
    assert!(
        kelvin_mae < KELVIN_MAE_MAX,
        "vertex temperatures should be within {KELVIN_MAE_MAX} K of the truth's on average, are {kelvin_mae} K off"
    );

    // The files, read back.
    let mesh = read_mesh_ply(&out).unwrap();
    assert_eq!(
        mesh.positions.len() as f64,
        f(&s, &["vertices"]),
        "mesh.ply should hold the vertices the command reported"
    );
    assert_eq!(mesh.triangles.len() as f64, f(&s, &["triangles"]));
    assert!(
        mesh.kelvin.iter().all(|k| (270.0..345.0).contains(k)),
        "every vertex temperature should be a scene temperature (270–345 K)"
    );
    assert!(mesh.rgb.is_none(), "a thermal-only run has no colour");
    let coloured = read_mesh_ply(&tmp.path().join("mesh_thermal.ply")).unwrap();
    assert_eq!(coloured.positions, mesh.positions);
    let colours = coloured.rgb.expect("mesh_thermal.ply should carry colours");
    assert!(
        colours.iter().any(|c| c != &colours[0]),
        "the colour-mapped copy should show more than one colour"
    );

    // The same run rendered on the Vulkan backend (lavapipe here) gives the same mesh.
    let out_vk = tmp.path().join("mesh_vk.ply");
    let v = mesh_json(&run_dir, &out_vk, &["--backend", "vulkan"]);
    let (nc, nv) = (f(&s, &["vertices"]), f(&v, &["vertices"]));
    assert!(
        (nc - nv).abs() <= 0.01 * nc,
        "the Vulkan render should give the CPU's mesh: {nv} vertices vs {nc}"
    );
    assert!(
        (f(&v, &["truth", "f_score"]) - f_score).abs() < 0.01,
        "the Vulkan mesh's F-score {} should match the CPU's {f_score}",
        f(&v, &["truth", "f_score"])
    );

    // A mesh that cannot be made: every voxel must be observed by more views than exist.
    let before = std::fs::read(&out).unwrap();
    let fail = Command::new(bin("s3tir-train"))
        .args([
            "mesh",
            run_dir.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--min-weight",
            "100",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&fail.stderr);
    assert!(
        !fail.status.success(),
        "meshing with --min-weight 100 should fail"
    );
    assert!(
        err.contains("no surface") && err.contains("100"),
        "the error should say no surface is seen by 100 views, says: {err}"
    );
    assert_eq!(
        std::fs::read(&out).unwrap(),
        before,
        "a failed mesh must leave the existing mesh.ply untouched"
    );
}

// Measured (seed 1, 64×48, 16 views, 600 iterations, CPU, default mesh options: voxel
// 24 mm from the views' pixel footprint): Chamfer 42.9 mm (accuracy 26.7, completeness 59.1),
// F-score 0.373 (precision 0.458, recall 0.314), vertex kelvin MAE 3.19 K; the Vulkan render
// gives the same mesh. The model's geometry is the limit, not the fusion: the same stage fed
// the true depth maps scores Chamfer 7.5 mm, F 0.930 (`true_depth_maps_fuse_into_the_true_
// surface`), while this model's rendered expected depth is off by a median 45–50 mm (p90
// 0.2–0.3 m) on its own training views — a thermal-only splat model of a mostly textureless
// scene places its primitives where they reproduce the images, not on the surface. Longer
// training (2 000 iterations, densified to 14.9 k primitives) gives better temperatures
// (0.91 K) and worse geometry (Chamfer 57.6 mm, F 0.287). Bounds: ~1.4× the measured error,
// ~0.8× the measured F-score.
const CHAMFER_MAX_M: f64 = 0.06;
const F_SCORE_MIN: f64 = 0.3;
const KELVIN_MAE_MAX: f64 = 4.5;
