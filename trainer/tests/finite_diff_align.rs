//! Proves: the thermal gradient alignment loss (`loss::align`, TGA-GS §3.4) has the exact
//! gradient w.r.t. every depth and alpha value (central differences, f64) on a smooth tilted
//! surface and on planes seen at grazing angles (85–89° from their normal), and end to end through
//! the renderer w.r.t. the geometric parameters (μ, log-scales, quaternion, opacity, β); that a
//! constant target gives exactly zero loss and gradient, that degenerate pixels (coincident
//! back-projected points), pixels below `min_alpha` and pixels across a 50 % depth jump
//! contribute nothing, and what the loss measures: 0 on a fronto-parallel plane, `∝ sin θ` for a
//! tilt about the thermal edge's axis, 0 for a tilt about the gradient's axis.
//! Does NOT prove: that the loss improves reconstructions (the trainer's ablation), or gradients
//! at the masks' edges and at `∇T·n = 0` (the scenes keep away from them).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::*;
use rand::Rng;
use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::loss::align::{
    AlignLoss, AlignSettings, normals, thermal_align, thermal_gradient,
};
use s3tir_trainer::primitive::Primitives;
use s3tir_trainer::render::{GBuffers, RenderSettings, render, render_backward};

const H: f64 = 1e-6;
/// Relative tolerance of the buffer-level checks.
const RTOL: f64 = 1e-6;
/// Absolute floor for near-zero gradients (typical entries are 1e-3–1e-1; the central
/// difference's rounding error is ~ε·L/h ≈ 1e-11).
const ATOL: f64 = 1e-9;

/// Central differences of `f` at `x` vs `analytic`; panics naming the worst mismatch, returns
/// the worst relative error over entries above the floor.
fn assert_fd(
    name: &str,
    x: &[f64],
    analytic: &[f64],
    f: impl Fn(&[f64]) -> f64,
    atol: f64,
    rtol: f64,
) -> f64 {
    assert_eq!(x.len(), analytic.len());
    let mut worst = (0usize, 0.0f64, 0.0f64, f64::NEG_INFINITY);
    let mut worst_rel = 0.0f64;
    let mut worst_rel_at = (0usize, 0.0f64);
    let mut nonzero = 0;
    for k in 0..x.len() {
        let mut p = x.to_vec();
        p[k] += H;
        let mut m = x.to_vec();
        m[k] -= H;
        let numeric = (f(&p) - f(&m)) / (2.0 * H);
        let a = analytic[k];
        assert!(
            a.is_finite(),
            "{name}: entry {k}: want a finite gradient, got {a}"
        );
        if a.abs() > 1e-9 {
            nonzero += 1;
        }
        let scale = a.abs().max(numeric.abs());
        if scale > atol / rtol {
            let rel = (a - numeric).abs() / scale;
            if rel > worst_rel {
                worst_rel = rel;
                worst_rel_at = (k, a);
            }
        }
        let excess = (a - numeric).abs() - (atol + rtol * scale);
        if excess > worst.3 {
            worst = (k, a, numeric, excess);
        }
    }
    assert!(
        worst.3 <= 0.0,
        "{name}: want analytic = central difference within {atol} + {rtol}·max; entry {} analytic \
         {} vs central difference {}",
        worst.0,
        worst.1,
        worst.2
    );
    assert!(
        nonzero > 0,
        "{name}: want a non-zero gradient (an identically zero one proves nothing)"
    );
    let max_abs = analytic.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    println!(
        "{name}: worst relative error {worst_rel:.2e} (entry {} = {:.3e}; largest |gradient| \
         {max_abs:.3e}) over {} entries",
        worst_rel_at.0,
        worst_rel_at.1,
        x.len()
    );
    worst_rel
}

/// Camera-frame ray of pixel `(x, y)`.
fn ray(cam: &PinholeCamera, x: usize, y: usize) -> [f64; 3] {
    [
        (x as f64 - cam.cx_px) / cam.fx_px,
        (y as f64 - cam.cy_px) / cam.fy_px,
        1.0,
    ]
}

/// Buffers of the plane `n·P = 1` (camera frame), expected depth times `1 + bump(x, y)`,
/// alpha from `alpha(x, y)`.
fn surface(
    cam: &PinholeCamera,
    n: [f64; 3],
    bump: impl Fn(usize, usize) -> f64,
    alpha: impl Fn(usize, usize) -> f64,
) -> GBuffers<f64> {
    let (w, h) = (cam.width, cam.height);
    let mut g = GBuffers::zeros(w, h, false);
    for y in 0..h {
        for x in 0..w {
            let r = ray(cam, x, y);
            let d = (1.0 + bump(x, y)) / (n[0] * r[0] + n[1] * r[1] + n[2] * r[2]);
            let p = y * w + x;
            g.alpha[p] = alpha(x, y);
            g.depth[p] = g.alpha[p] * d;
        }
    }
    g
}

fn align(
    g: &GBuffers<f64>,
    target: &[f64],
    cam: &PinholeCamera,
    s: &AlignSettings,
    weight: f64,
) -> (AlignLoss, GBuffers<f64>) {
    let mut up = GBuffers::zeros(g.width, g.height, false);
    let l = thermal_align(g, target, cam, s, weight, &mut up).unwrap();
    (l, up)
}

/// FD of the loss w.r.t. every depth and alpha value of `g`.
fn check_buffers(name: &str, g: &GBuffers<f64>, target: &[f64], cam: &PinholeCamera, weight: f64) {
    let s = AlignSettings::default();
    let (l, up) = align(g, target, cam, &s, weight);
    assert!(
        l.loss.is_finite() && up.all_finite(),
        "{name}: want a finite loss and gradient, got loss {}",
        l.loss
    );
    let loss_of = |gb: &GBuffers<f64>| align(gb, target, cam, &s, weight).0.loss;
    assert_fd(
        &format!("{name}: dL/d(depth)"),
        &g.depth,
        &up.depth,
        |x| {
            loss_of(&GBuffers {
                depth: x.to_vec(),
                ..g.clone()
            })
        },
        ATOL,
        RTOL,
    );
    assert_fd(
        &format!("{name}: dL/d(alpha)"),
        &g.alpha,
        &up.alpha,
        |x| {
            loss_of(&GBuffers {
                alpha: x.to_vec(),
                ..g.clone()
            })
        },
        ATOL,
        RTOL,
    );
}

/// 12×10 view of a tilted plane (~3.3 m) with a small sinusoid, alpha in [0.6, 1].
fn smooth_surface() -> (GBuffers<f64>, PinholeCamera) {
    let cam = front_camera(12, 10, 14.0);
    let mut r = rng(31);
    let alphas: Vec<f64> = (0..120).map(|_| r.random_range(0.6..1.0)).collect();
    let g = surface(
        &cam,
        [0.06, -0.04, 0.3],
        |x, y| 0.02 * (0.9 * x as f64 + 0.5 * y as f64).sin(),
        |x, y| alphas[y * 12 + x],
    );
    (g, cam)
}

#[test]
fn gradient_matches_finite_differences_on_a_smooth_surface() {
    let (g, cam) = smooth_surface();
    let target = random_plane(32, 120, 0.0, 1.0);
    let (l, _) = align(&g, &target, &cam, &AlignSettings::default(), 0.7);
    assert_eq!(
        l.pixels,
        11 * 9,
        "want every pixel with both forward neighbours (11×9) to contribute"
    );
    assert!(l.loss > 0.0, "want a positive loss against a random target");
    check_buffers("smooth surface", &g, &target, &cam, 0.7);
}

#[test]
fn gradient_through_the_renderer_matches_finite_differences() {
    let cam = front_camera(20, 16, 18.0);
    let mut r = rng(41);
    let mut prims = Primitives::<f64>::new(1, None);
    for (i, beta) in [2.0, 2.0, 3.0, 2.5, 6.0, 2.0].into_iter().enumerate() {
        let mut init = random_primitive(&mut r, [0.0, 0.0, 3.0], beta, 1, 0);
        init.mean_m[0] = -1.0 + 0.4 * i as f64 + r.random_range(-0.1..0.1);
        init.mean_m[1] = r.random_range(-0.5..0.5);
        init.scale_m = [
            r.random_range(0.4..0.7),
            r.random_range(0.4..0.7),
            r.random_range(0.2..0.5),
        ];
        init.opacity = r.random_range(0.85..0.95);
        prims.push(&init);
    }
    let rs = RenderSettings::default();
    let settings = AlignSettings::default();
    let target = random_plane(42, 20 * 16, 0.0, 1.0);
    let weight = 0.5;
    let out = render(&prims, &cam, &rs).unwrap();
    let (l, up) = align(&out, &target, &cam, &settings, weight);
    println!(
        "render→align: {} of {} pixels contribute",
        l.pixels,
        20 * 16
    );
    assert!(
        l.pixels > 60,
        "want a scene where many pixels have normals, got {}",
        l.pixels
    );
    let g = render_backward(&prims, &cam, &rs, &up).unwrap();
    let loss = |p: &Primitives<f64>| {
        let out = render(p, &cam, &rs).unwrap();
        align(&out, &target, &cam, &settings, weight).0.loss
    };
    let names: Vec<&str> = prims.groups().iter().map(|(n, _)| n.name()).collect();
    for (gi, name) in names.iter().enumerate() {
        let analytic = g.groups()[gi].1.clone();
        if ["omega_low", "band_amp", "band_freq", "band_phase", "sh"].contains(name) {
            assert!(
                analytic.iter().all(|v| *v == 0.0),
                "{name} only shapes the thermal plane: want an exactly zero gradient"
            );
            continue;
        }
        let values = prims.groups()[gi].1.clone();
        assert_fd(
            &format!("render→align wrt {name}"),
            &values,
            &analytic,
            |x| {
                let mut p = prims.clone();
                *p.groups_mut()[gi].1 = x.to_vec();
                loss(&p)
            },
            1e-9,
            1e-5,
        );
    }
}

#[test]
fn constant_target_gives_exactly_zero_loss_and_gradient() {
    let (g, cam) = smooth_surface();
    let target = vec![0.42; 120];
    let (l, up) = align(&g, &target, &cam, &AlignSettings::default(), 1.0);
    assert_eq!(
        l.loss, 0.0,
        "a constant target has no gradient: want loss 0"
    );
    assert_eq!(l.pixels, 99, "want the masks unchanged by the target");
    assert!(
        up.depth.iter().chain(&up.alpha).all(|v| *v == 0.0),
        "want exactly zero depth/alpha gradients for a constant target"
    );
}

#[test]
fn grazing_planes_have_finite_exact_gradients() {
    // f = 1000 px: the plane stays in front of the camera over the image, and the relative depth
    // step per pixel (~ tan θ / f) stays under 10 % up to 89°. Stiff: the worst alpha entry at 85°
    // is 5.9e-7 relative at h = 1e-6, and it is truncation (h²: 5.0e-8 at h = 3e-7), not a
    // wrong gradient; D = depth/alpha makes alpha steps the larger depth steps.
    let cam = front_camera(12, 10, 1000.0);
    let target = random_plane(51, 120, 0.0, 1.0);
    let mut r = rng(52);
    let alphas: Vec<f64> = (0..120).map(|_| r.random_range(0.6..1.0)).collect();
    let phi = 30f64.to_radians();
    for deg in [85.0, 87.0, 89.0] {
        let th = f64::to_radians(deg);
        // unit normal at θ from the optical axis, plane through (0, 0, 3)
        let n = [th.sin() * phi.cos(), th.sin() * phi.sin(), th.cos()];
        let nn = [n[0] / (3.0 * th.cos()), n[1] / (3.0 * th.cos()), 1.0 / 3.0];
        let g = surface(&cam, nn, |_, _| 0.0, |x, y| alphas[y * 12 + x]);
        let (l, _) = align(&g, &target, &cam, &AlignSettings::default(), 1.0);
        assert_eq!(l.pixels, 99, "{deg}°: want every inner pixel to contribute");
        let normals = normals(&g, &cam, &AlignSettings::default()).unwrap();
        let got = normals[5 * 12 + 5].expect("an inner pixel has a normal");
        let err = (0..3).map(|i| (got[i] - n[i]).abs()).fold(0.0, f64::max);
        println!("{deg}°: loss {:.4e}, normal error {err:.1e}", l.loss);
        assert!(
            err < 1e-9,
            "{deg}°: want the plane's normal {n:?}, got {got:?}"
        );
        check_buffers(&format!("grazing {deg}°"), &g, &target, &cam, 1.0);
    }
}

#[test]
fn degenerate_pixels_are_skipped_without_nan() {
    let cam = front_camera(6, 5, 8.0);
    let target = random_plane(61, 30, 0.0, 1.0);
    let zeroed = [(2, 2), (3, 2), (2, 3)];
    // D = 0: the three back-projected points coincide (t_u = t_v = 0); D = 1e-200: the cross
    // product underflows to 0.
    for d in [0.0, 1e-200] {
        let mut g = surface(&cam, [0.02, 0.03, 0.3], |_, _| 0.0, |_, _| 0.8);
        for &(x, y) in &zeroed {
            g.depth[y * 6 + x] = 0.8 * d;
        }
        let (l, up) = align(&g, &target, &cam, &AlignSettings::default(), 1.0);
        assert!(
            l.loss.is_finite() && up.all_finite(),
            "D = {d}: want a finite loss and gradient, got loss {}",
            l.loss
        );
        // (2,2): degenerate; (1,2), (2,1), (3,1), (1,3), (3,2), (2,3): a depth step to or from 0.
        assert_eq!(
            l.pixels,
            5 * 4 - 7,
            "D = {d}: want the 20 inner pixels minus the degenerate one and 6 across the step"
        );
        let normals = normals(&g, &cam, &AlignSettings::default()).unwrap();
        assert!(
            normals[2 * 6 + 2].is_none(),
            "D = {d}: want no normal at the degenerate pixel"
        );
        for &(x, y) in &zeroed {
            let p = y * 6 + x;
            assert!(
                up.depth[p] == 0.0 && up.alpha[p] == 0.0,
                "D = {d}: want no gradient at skipped pixel ({x}, {y})"
            );
        }
    }
}

#[test]
fn low_alpha_and_depth_jumps_contribute_nothing() {
    let (w, h) = (10, 8);
    let cam = front_camera(w, h, 12.0);
    let target = random_plane(71, w * h, 0.0, 1.0);
    let low = |x: usize, y: usize| (1..=2).contains(&x) && (1..=3).contains(&y);
    let build = |jump: f64| {
        surface(
            &cam,
            [0.03, 0.02, 0.3],
            |x, _| if x >= 6 { jump - 1.0 } else { 0.0 },
            |x, y| if low(x, y) { 0.3 } else { 0.8 },
        )
    };
    // Independent count: p, right and down neighbours have alpha ≥ 0.5 and are on the same side
    // of the jump between columns 5 and 6.
    let mut expected = 0;
    for y in 0..h - 1 {
        for x in 0..w - 1 {
            if !(low(x, y) || low(x + 1, y) || low(x, y + 1) || x == 5) {
                expected += 1;
            }
        }
    }
    let s = AlignSettings::default();
    let (l15, up) = align(&build(1.5), &target, &cam, &s, 1.0);
    assert_eq!(
        l15.pixels, expected,
        "want pixels below min_alpha and across the 50 % jump masked"
    );
    for y in 0..h {
        for x in 0..w {
            if low(x, y) {
                let p = y * w + x;
                assert!(
                    up.depth[p] == 0.0 && up.alpha[p] == 0.0,
                    "want no gradient at low-alpha pixel ({x}, {y}), got ({}, {})",
                    up.depth[p],
                    up.alpha[p]
                );
            }
        }
    }
    // A plane scaled about the camera keeps its normals: only pixels straddling the jump would
    // notice a different jump, and they are masked.
    let (l17, _) = align(&build(1.7), &target, &cam, &s, 1.0);
    assert!(
        (l17.loss - l15.loss).abs() <= 1e-12 * l15.loss && l17.pixels == l15.pixels,
        "want the loss independent of the jump's size: {} (50 %) vs {} (70 %)",
        l15.loss,
        l17.loss
    );
    // Below the threshold (5 %) the step is a surface again.
    let (l05, _) = align(&build(1.05), &target, &cam, &s, 1.0);
    assert_eq!(
        l05.pixels,
        expected + (h - 1),
        "want the 7 pixels of column 5 to contribute at a 5 % step"
    );
}

#[test]
fn loss_measures_tilt_across_the_thermal_edge() {
    let (w, h) = (16, 12);
    let cam = front_camera(w, h, 16.0);
    // Thermal edge along the image's y axis (gradient along x), a smooth step over 3 px.
    let target: Vec<f64> = (0..w * h)
        .map(|p| 1.0 / (1.0 + (-((p % w) as f64 - 7.5)).exp()))
        .collect();
    let (gx, _) = thermal_gradient(&target, w, h).unwrap();
    let s = AlignSettings::default();
    let inner = (w - 1) * (h - 1);
    let sum_gx: f64 = (0..w * h)
        .filter(|p| p % w < w - 1 && p / w < h - 1)
        .map(|p| gx[p].abs())
        .sum();
    // plane through (0, 0, 3) with unit normal n
    let plane = |n: [f64; 3]| {
        let k = 3.0 * n[2];
        surface(&cam, [n[0] / k, n[1] / k, n[2] / k], |_, _| 0.0, |_, _| 0.9)
    };
    let (flat, _) = align(&plane([0.0, 0.0, 1.0]), &target, &cam, &s, 1.0);
    assert_eq!(flat.pixels, inner, "want every inner pixel of the plane");
    assert_eq!(flat.loss, 0.0, "fronto-parallel plane: want loss 0");
    let mut last = 0.0;
    for deg in [5.0, 10.0, 20.0, 30.0] {
        let th = f64::to_radians(deg);
        // tilt about the y axis (parallel to the edge): n gains an x component
        let (across, _) = align(&plane([th.sin(), 0.0, th.cos()]), &target, &cam, &s, 1.0);
        // every contributing pixel has s = gx·sin θ
        let want = sum_gx * th.sin() / (w * h) as f64;
        println!("tilt {deg}° about the edge axis: loss {:.6e}", across.loss);
        assert!(
            across.pixels == inner && (across.loss - want).abs() <= 1e-12 * want,
            "tilt {deg}° about the edge axis: want loss Σ|gx|·sin θ/(WH) = {want} over {inner} px, \
             got {} over {}",
            across.loss,
            across.pixels
        );
        assert!(
            across.loss > last,
            "want the loss to grow with the tilt: {deg}° gives {} after {last}",
            across.loss
        );
        last = across.loss;
        // tilt about the x axis (along the gradient): n gains a y component, along the edge
        let (along, _) = align(&plane([0.0, th.sin(), th.cos()]), &target, &cam, &s, 1.0);
        assert!(
            along.pixels == inner && along.loss.abs() < 1e-15,
            "tilt {deg}° about the gradient's axis: want loss ~0 over {inner} px, got {} over {}",
            along.loss,
            along.pixels
        );
    }
}
