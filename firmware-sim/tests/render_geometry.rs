//! Proves: a noise-free, blur-free rendered checkerboard has its corners where the analytic
//! projection puts them, to < 0.02 px, measured without OpenCV: each board edge's sub-pixel
//! position in each row/column is recovered from the area-integrated intensities (the sum of
//! fractional coverages), lines are fitted to both edges through a corner and intersected.
//! This checks the pixel-centre convention, the pose convention and the area integration.
//! Does not prove anything about distortion accuracy beyond the zero-distortion camera used
//! here (straight edges are needed for the line fit), nor about thermal rendering.
#![allow(clippy::unwrap_used)]

use glam::{DQuat, DVec2, DVec3};
use s3tir_calib::{BrownConrady, CameraModel, Intrinsics, Rigid3};
use s3tir_firmware_sim::board::BoardSpec;
use s3tir_firmware_sim::render::{RayGrid, render_plane};
use s3tir_firmware_sim::rig::VisibleBoardTexture;

fn camera() -> CameraModel {
    CameraModel {
        width_px: 480,
        height_px: 360,
        intrinsics: Intrinsics {
            fx: 520.0,
            fy: 515.0,
            cx: 241.3,
            cy: 178.6,
        },
        distortion: BrownConrady::default(),
    }
}

/// Sub-pixel crossing of the edge in row `v` between columns `u0..=u1`, given the values of
/// the left (`a`) and right (`b`) sides: x = u0 − ½ + Σ coverage of `a`.
fn row_crossing(img: &[f64], w: usize, v: usize, u0: usize, u1: usize, a: f64, b: f64) -> f64 {
    let cov: f64 = (u0..=u1).map(|u| (img[v * w + u] - b) / (a - b)).sum();
    u0 as f64 - 0.5 + cov
}

fn col_crossing(img: &[f64], w: usize, u: usize, v0: usize, v1: usize, a: f64, b: f64) -> f64 {
    let cov: f64 = (v0..=v1).map(|v| (img[v * w + u] - b) / (a - b)).sum();
    v0 as f64 - 0.5 + cov
}

/// Least-squares line x = p + q·t through (t, x) samples.
fn fit(samples: &[(f64, f64)]) -> (f64, f64) {
    let n = samples.len() as f64;
    let (st, sx) = samples
        .iter()
        .fold((0.0, 0.0), |a, s| (a.0 + s.0, a.1 + s.1));
    let (mt, mx) = (st / n, sx / n);
    let (mut num, mut den) = (0.0, 0.0);
    for (t, x) in samples {
        num += (t - mt) * (x - mx);
        den += (t - mt) * (t - mt);
    }
    let q = num / den;
    (mx - q * mt, q)
}

#[test]
fn rendered_corners_match_the_analytic_projection() {
    let cam = camera();
    let grid = RayGrid::new(&cam);
    let board = BoardSpec::default();
    let tex = VisibleBoardTexture { board: &board };
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    // Moderately tilted board (edges stay closer to the image axes than 45°).
    let rotation = DQuat::from_euler(glam::EulerRot::ZYX, 0.12, 0.25, -0.2);
    let (x0, y0, x1, y1) = board.extent_m();
    let centre = DVec3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
    let cam_from_board = Rigid3::new(rotation, DVec3::new(0.01, -0.005, 0.75) - rotation * centre);
    let img = render_plane(&grid, &cam_from_board, 4, &tex, 0.3);
    let (black, white) = (board.reflectance_black, board.reflectance_white);
    let mut worst: f64 = 0.0;
    let mut measured = 0;
    for j in 0..board.inner_rows {
        for i in 0..board.inner_cols {
            let p = DVec3::new(
                f64::from(i) * board.square_m,
                f64::from(j) * board.square_m,
                0.0,
            );
            let truth = cam.project(cam_from_board.transform_point(p)).unwrap();
            // Directions of the two board edges through this corner, in the image.
            let ex = cam
                .project(cam_from_board.transform_point(p + DVec3::X * 0.01))
                .unwrap()
                - truth;
            let ey = cam
                .project(cam_from_board.transform_point(p + DVec3::Y * 0.01))
                .unwrap()
                - truth;
            // The board-y edge is the "mostly vertical" one; the board-x edge "mostly horizontal".
            assert!(
                ey.y.abs() > ey.x.abs() && ex.x.abs() > ex.y.abs(),
                "pose keeps edges near the axes"
            );
            let (cu, cv) = (truth.x.round() as i64, truth.y.round() as i64);
            // Vertical edge: rows 3..=9 px above and below; window ±4 px around the edge.
            let mut vert = Vec::new();
            for dv in (-9i64..=-3).chain(3..=9) {
                let v = (cv + dv) as usize;
                let x_est = truth.x + ey.x / ey.y * (v as f64 - truth.y);
                let (u0, u1) = (
                    (x_est.round() as i64 - 4) as usize,
                    (x_est.round() as i64 + 4) as usize,
                );
                let (left, right) = (img[v * w + u0], img[v * w + u1]);
                let pure = |x: f64| (x - black).abs() < 1e-9 || (x - white).abs() < 1e-9;
                assert!(
                    pure(left) && pure(right) && (left - right).abs() > 0.5,
                    "window ends must be pure squares at row {v}"
                );
                vert.push((v as f64, row_crossing(&img, w, v, u0, u1, left, right)));
            }
            let mut horiz = Vec::new();
            for du in (-9i64..=-3).chain(3..=9) {
                let u = (cu + du) as usize;
                let y_est = truth.y + ex.y / ex.x * (u as f64 - truth.x);
                let (v0, v1) = (
                    (y_est.round() as i64 - 4) as usize,
                    (y_est.round() as i64 + 4) as usize,
                );
                let (top, bottom) = (img[v0 * w + u], img[v1 * w + u]);
                horiz.push((u as f64, col_crossing(&img, w, u, v0, v1, top, bottom)));
            }
            let (pv, qv) = fit(&vert); // x = pv + qv·y
            let (ph, qh) = fit(&horiz); // y = ph + qh·x
            // Intersect: x = pv + qv (ph + qh x)
            let x = (pv + qv * ph) / (1.0 - qv * qh);
            let y = ph + qh * x;
            let err = (DVec2::new(x, y) - truth).length();
            worst = worst.max(err);
            measured += 1;
        }
    }
    assert_eq!(measured, (board.inner_cols * board.inner_rows) as usize);
    eprintln!("worst corner error {worst:.5} px over {measured} corners");
    assert!(
        worst < 0.02,
        "worst corner error {worst:.4} px, want < 0.02 px"
    );
    assert!(h > 0);
}
