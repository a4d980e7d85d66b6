//! Diagnostic: the front end's corners against the simulator's truth, per view.
//!
//! `cargo run -p s3tir-calib --example sim_corner_error -- SET_DIR [thermal|rgb] [corners]`
//! where SET_DIR is an `s3tir-firmware-sim board` output (board.toml, truth.json, images).
//! Prints, per view, the RMS, largest and mean error of the detected corners against the true
//! corners projected through the true camera (`corners`: also every corner off by > 0.06 px),
//! and the total. How the saddle-fit refinement was measured (see `frontend` docs).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use glam::{DMat3, DQuat, DVec2, DVec3};
use s3tir_calib::detect::board::BoardSpec;
use s3tir_calib::detect::frontend::detect_board;
use s3tir_calib::detect::scalar::load_scalar;
use s3tir_calib::{CameraModel, Rigid3};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::PathBuf::from(&args[1]);
    let cam_name = args.get(2).map(String::as_str).unwrap_or("thermal");
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).unwrap()).unwrap();
    let cam: CameraModel = serde_json::from_value(truth[cam_name].clone()).unwrap();
    let board = BoardSpec::load(&dir.join("board.toml")).unwrap();
    let obj = board.object_points_m();
    let rgb_from_thermal = pose(&truth["rgb_from_thermal"]);
    let mut all = Vec::new();
    let mut biases = Vec::new();
    for v in truth["views"].as_array().unwrap() {
        let idx = v["index"].as_u64().unwrap();
        let t_from_b = pose(&v["thermal_from_board"]);
        let c_from_b = if cam_name == "thermal" {
            t_from_b
        } else {
            rgb_from_thermal.compose(&t_from_b)
        };
        let truth_px: Vec<Option<DVec2>> = obj
            .iter()
            .map(|p| cam.project(c_from_b.transform_point(*p)))
            .collect();
        let path = dir.join(v[cam_name].as_str().unwrap());
        let img = load_scalar(&path, cam_name == "thermal", Default::default()).unwrap();
        let t0 = std::time::Instant::now();
        let det = detect_board(&img, &board).unwrap();
        let dt = t0.elapsed().as_secs_f64();
        let Ok(det) = det else {
            println!(
                "view {idx:2}: {det:?}  full={}",
                v["board_fully_in_thermal"]
            );
            continue;
        };
        let n = obj.len();
        let mut best = (f64::INFINITY, Vec::new());
        for rev in [false, true] {
            let mut errs = Vec::new();
            for (i, t) in truth_px.iter().enumerate() {
                let d = det.corners_px[if rev { n - 1 - i } else { i }];
                if let Some(t) = t {
                    errs.push(d - *t);
                }
            }
            let rms =
                (errs.iter().map(|e| e.length_squared()).sum::<f64>() / errs.len() as f64).sqrt();
            if rms < best.0 {
                best = (rms, errs);
            }
        }
        if args.get(3).is_some_and(|a| a == "corners") {
            for (i, e) in best.1.iter().enumerate() {
                if e.length() > 0.06 {
                    println!("   corner {i}: err ({:+.3},{:+.3})", e.x, e.y);
                }
            }
        }
        let mean = best.1.iter().copied().sum::<DVec2>() / best.1.len() as f64;
        let max = best.1.iter().map(|e| e.length()).fold(0.0, f64::max);
        let spacing = (truth_px[1].unwrap() - truth_px[0].unwrap()).length();
        println!(
            "view {idx:2}: {} rms {:.4} px max {:.3} bias ({:+.3},{:+.3}) spacing {:.1} px z {:.2} m det {} rough {:.3} {:.2}s",
            if best.1.len() < n {
                "partial"
            } else {
                "full   "
            },
            best.0,
            max,
            mean.x,
            mean.y,
            spacing,
            t_from_b.translation_m.z,
            det.detector,
            det.roughness_px,
            dt
        );
        all.extend(best.1.iter().copied());
        biases.push(mean);
    }
    let rms = (all.iter().map(|e| e.length_squared()).sum::<f64>() / all.len() as f64).sqrt();
    let bias_rms =
        (biases.iter().map(|e| e.length_squared()).sum::<f64>() / biases.len() as f64).sqrt();
    println!(
        "TOTAL {} corners rms {rms:.4} px; per-view bias rms {bias_rms:.4} px; views {}",
        all.len(),
        biases.len()
    );
}

fn pose(v: &serde_json::Value) -> Rigid3 {
    let r = &v["rotation"];
    let g = |i: usize, j: usize| r[i][j].as_f64().unwrap();
    let m = DMat3::from_cols(
        DVec3::new(g(0, 0), g(1, 0), g(2, 0)),
        DVec3::new(g(0, 1), g(1, 1), g(2, 1)),
        DVec3::new(g(0, 2), g(1, 2), g(2, 2)),
    );
    let t = &v["translation_m"];
    Rigid3::new(
        DQuat::from_mat3(&m),
        DVec3::new(
            t[0].as_f64().unwrap(),
            t[1].as_f64().unwrap(),
            t[2].as_f64().unwrap(),
        ),
    )
}
