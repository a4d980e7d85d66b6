//! Proves: the `board` set writer is deterministic (same seed ⇒ identical bytes in every file,
//! different seed ⇒ different images), writes the documented layout, and its planned poses
//! meet the spec: tilts up to ±45°, whole board inside both images except the planned partial
//! views, image regions near all four corners covered, an asymmetric inner-corner grid.
//! The thermal PNG reproduces the model's apparent contrast (coated vs uncoated squares) to 0.2 K.
//! Does not prove that a detector finds the board (that is calib's test, on these files).
#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec3;
use s3tir_firmware_sim::board::BoardSpec;
use s3tir_firmware_sim::dataset::{BoardSetConfig, Polarity, write_board_set};
use s3tir_firmware_sim::rig::{Rig, corners_inside, plan_board_views};
use s3tir_firmware_sim::sensor::{RgbProfile, ThermalProfile};

fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    for sub in ["", "thermal", "rgb"] {
        for e in std::fs::read_dir(dir.join(sub)).unwrap() {
            let p = e.unwrap().path();
            if p.is_file() {
                out.insert(
                    p.strip_prefix(dir).unwrap().display().to_string(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn config(out: &Path, seed: u64) -> BoardSetConfig {
    BoardSetConfig {
        out_dir: out.to_path_buf(),
        views: 2,
        rig: Rig::new(ThermalProfile::lepton35(), RgbProfile::hd720()),
        board: BoardSpec::default(),
        polarity: Polarity::Cooled,
        seed,
        first_view_s: 60.0,
        view_interval_s: 8.0,
    }
}

#[test]
fn same_seed_writes_identical_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        tmp.path().join("a"),
        tmp.path().join("b"),
        tmp.path().join("c"),
    );
    write_board_set(&config(&a, 7), &mut |_, _| {}).unwrap();
    write_board_set(&config(&b, 7), &mut |_, _| {}).unwrap();
    write_board_set(&config(&c, 8), &mut |_, _| {}).unwrap();
    let (fa, fb, fc) = (files(&a), files(&b), files(&c));
    let names: Vec<&String> = fa.keys().collect();
    assert_eq!(
        names,
        vec![
            "board.toml",
            "rgb/0000.png",
            "rgb/0001.png",
            "thermal/0000.png",
            "thermal/0001.png",
            "truth.json"
        ],
        "documented layout"
    );
    for (name, bytes) in &fa {
        assert!(
            fb[name] == *bytes,
            "{name} differs between two runs with the same seed"
        );
    }
    assert_ne!(
        fa["thermal/0000.png"], fc["thermal/0000.png"],
        "another seed, another image"
    );
    let truth: serde_json::Value = serde_json::from_slice(&fa["truth.json"]).unwrap();
    let r = &truth["rgb_from_thermal"]["rotation"];
    assert_eq!(r.as_array().unwrap().len(), 3, "3x3 rotation");
    let t = truth["rgb_from_thermal"]["translation_m"]
        .as_array()
        .unwrap();
    let baseline = t
        .iter()
        .map(|v| v.as_f64().unwrap().powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        (0.05..0.08).contains(&baseline),
        "baseline {baseline} m, want 5–8 cm"
    );
    assert_eq!(truth["views"].as_array().unwrap().len(), 2);
    // The thermal image carries the physics: coated-minus-uncoated square centres measured in
    // the PNG (centikelvin) equal the model's apparent contrast recorded in truth.json.
    let cam: s3tir_calib::CameraModel = serde_json::from_value(truth["thermal"].clone()).unwrap();
    let view = &truth["views"][0];
    let rot: Vec<Vec<f64>> =
        serde_json::from_value(view["thermal_from_board"]["rotation"].clone()).unwrap();
    let tr: Vec<f64> =
        serde_json::from_value(view["thermal_from_board"]["translation_m"].clone()).unwrap();
    let m = glam::DMat3::from_cols_array_2d(&[
        [rot[0][0], rot[1][0], rot[2][0]],
        [rot[0][1], rot[1][1], rot[2][1]],
        [rot[0][2], rot[1][2], rot[2][2]],
    ]);
    let img = image::load_from_memory(&fa["thermal/0000.png"])
        .unwrap()
        .into_luma16();
    let board = BoardSpec::default();
    let (mut coated, mut uncoated) = (Vec::new(), Vec::new());
    for j in -1..i64::from(board.inner_rows) {
        for i in -1..i64::from(board.inner_cols) {
            let p = DVec3::new(
                (i as f64 + 0.5) * board.square_m,
                (j as f64 + 0.5) * board.square_m,
                0.0,
            );
            let px = cam.project(m * p + DVec3::from_slice(&tr)).unwrap();
            let (u, v) = (px.x.round() as i64, px.y.round() as i64);
            if u < 2
                || v < 2
                || u >= i64::from(cam.width_px) - 2
                || v >= i64::from(cam.height_px) - 2
            {
                continue;
            }
            let k = f64::from(img.get_pixel(u as u32, v as u32).0[0]) / 100.0;
            if (i + j).rem_euclid(2) == 0 {
                coated.push(k)
            } else {
                uncoated.push(k)
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let measured = mean(&coated) - mean(&uncoated);
    let want = view["apparent_contrast_k"].as_f64().unwrap();
    eprintln!(
        "apparent contrast: PNG {measured:.3} K, model {want:.3} K ({} + {} squares)",
        coated.len(),
        uncoated.len()
    );
    assert!(
        (measured - want).abs() < 0.2,
        "apparent contrast in the PNG {measured:.2} K, model {want:.2} K (want within 0.2 K)"
    );
    let toml_text = String::from_utf8(fa["board.toml"].clone()).unwrap();
    let board: toml::Table = toml_text.parse().unwrap();
    assert_eq!(board["board"]["inner_corners"].as_array().unwrap().len(), 2);
}

#[test]
fn planned_views_cover_the_image_with_tilts_and_a_few_partial_views() {
    let rig = Rig::new(ThermalProfile::lepton35(), RgbProfile::hd720());
    let board = BoardSpec::default();
    assert_ne!(
        board.inner_cols % 2,
        board.inner_rows % 2,
        "corner counts of different parity"
    );
    let views = plan_board_views(&rig, &board, 30, 1).unwrap();
    let n_corners = (board.inner_cols * board.inner_rows) as usize;
    let partial = views.iter().filter(|v| !v.full_in_thermal).count();
    assert!(
        (2..=6).contains(&partial),
        "a few partial views, got {partial} of 30"
    );
    let full_both = views
        .iter()
        .filter(|v| v.full_in_thermal && v.full_in_rgb)
        .count();
    assert!(
        full_both >= 24,
        "most views fully inside both images, got {full_both}"
    );
    let cam = rig.thermal.camera;
    let (w, h) = (f64::from(cam.width_px), f64::from(cam.height_px));
    let mut quadrant_hits = [false; 4];
    let mut max_tilt: f64 = 0.0;
    for v in &views {
        let normal = v.thermal_from_board.transform_vector(DVec3::NEG_Z);
        max_tilt = max_tilt.max(normal.angle_between(DVec3::NEG_Z).to_degrees());
        let seen = corners_inside(&cam, &v.thermal_from_board, &board);
        assert!(
            seen * 10 >= n_corners * 3,
            "every view shows ≥ 30 % of the corners, got {seen}"
        );
        for p in board.inner_corners_m() {
            if let Some(px) = cam.project(v.thermal_from_board.transform_point(p)) {
                let q = usize::from(px.x > w / 2.0) + 2 * usize::from(px.y > h / 2.0);
                let near_corner =
                    (px.x < 0.2 * w || px.x > 0.8 * w) && (px.y < 0.2 * h || px.y > 0.8 * h);
                if near_corner {
                    quadrant_hits[q] = true;
                }
            }
        }
    }
    assert!(
        quadrant_hits.iter().all(|&q| q),
        "board corners seen near all four image corners: {quadrant_hits:?}"
    );
    assert!(
        (25.0..=64.0).contains(&max_tilt),
        "largest tilt {max_tilt:.1}°, want a strongly tilted view ≤ ±45° per axis"
    );
}
