//! Proves: the forward pass renders the model of the paper/brief, checked against an independent
//! brute-force evaluation: for each pixel the support is maximised along the ray by dense
//! sampling (not the closed form), α = min(0.99, o·S), F = ReLU(ω_low + Σ ω_j cos(2π f_jᵀ(x−μ)+φ_j))
//! at that point, and two primitives blend front to back in the order of their centres' camera
//! depth (C = α₁v₁ + (1−α₁)α₂v₂) for the image and every G-buffer.
//! Also: invalid shapes, SH degrees and cameras are errors that name the problem.
//! Does NOT prove: gradients (finite_diff_*.rs), culling (culling.rs), numerical extremes (stiff.rs).
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::primitive::{PrimitiveInit, Primitives, rotation_from_quat};
use s3tir_trainer::render::{ALPHA_MAX, ALPHA_MIN, RenderSettings, render};

struct Brute {
    alpha: f64,
    f: f64,
    t: f64,
    beta: f64,
    low: f64,
    high: f64,
}

/// Dense search of the support's peak along the pixel ray, then the model's values there.
fn brute(p: &Primitives<f64>, i: usize, cam: &PinholeCamera, x: usize, y: usize) -> Option<Brute> {
    let c = cam.centre_world();
    let e = cam.unproject(x as f64, y as f64, 1.0);
    let d = [e[0] - c[0], e[1] - c[1], e[2] - c[2]];
    let mu = p.mean(i);
    let (rot, _, _) = rotation_from_quat(p.quat(i));
    let s = p.scales(i);
    let m2 = |t: f64| -> f64 {
        let v = [
            c[0] + t * d[0] - mu[0],
            c[1] + t * d[1] - mu[1],
            c[2] + t * d[2] - mu[2],
        ];
        (0..3)
            .map(|r| ((rot[r] * v[0] + rot[3 + r] * v[1] + rot[6 + r] * v[2]) / s[r]).powi(2))
            .sum()
    };
    // coarse grid then ternary search (q is a convex quadratic in t)
    let (mut lo, mut hi) = (0.0f64, 20.0f64);
    let mut best = lo;
    for k in 0..=20_000 {
        let t = 20.0 * k as f64 / 20_000.0;
        if m2(t) < m2(best) {
            best = t;
        }
    }
    lo = (best - 0.002).max(0.0);
    hi = hi.min(best + 0.002);
    for _ in 0..200 {
        let (a, b) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        if m2(a) < m2(b) { hi = b } else { lo = a }
    }
    let t = 0.5 * (lo + hi);
    let (beta, _) = p.beta(i);
    let (o, _) = p.opacity(i);
    let alpha = (o * (-m2(t).powf(beta / 2.0)).exp()).min(ALPHA_MAX);
    if alpha < ALPHA_MIN || t <= RenderSettings::default().near_m {
        return None;
    }
    let delta = [
        c[0] + t * d[0] - mu[0],
        c[1] + t * d[1] - mu[1],
        c[2] + t * d[2] - mu[2],
    ];
    let mut pre = p.omega_low[i];
    let mut high = 0.0;
    for j in 0..p.bands {
        let k = p.bands * i + j;
        let f = &p.band_freq[3 * k..3 * k + 3];
        let th = std::f64::consts::TAU * (f[0] * delta[0] + f[1] * delta[1] + f[2] * delta[2])
            + p.band_phase[k];
        pre += p.band_amp[k] * th.cos();
        high += p.band_amp[k].abs();
    }
    Some(Brute {
        alpha,
        f: pre.max(0.0),
        t,
        beta,
        low: p.omega_low[i],
        high,
    })
}

#[test]
fn forward_matches_brute_force_model_for_two_overlapping_primitives() {
    let cam = PinholeCamera::look_at(
        [0.3, -0.2, -0.5],
        [0.0, 0.0, 3.0],
        [0.0, -1.0, 0.0],
        20.0,
        20,
        16,
    );
    let mut p = Primitives::<f64>::new(2, None);
    // listed back one first: the renderer must sort by centre depth, not by index
    p.push(&PrimitiveInit {
        mean_m: [0.1, 0.0, 3.5],
        scale_m: [0.8, 0.5, 0.3],
        quat: [0.9, 0.2, -0.1, 0.3],
        opacity: 0.8,
        beta: 6.0,
        omega_low: 0.6,
        bands: vec![(0.3, [0.7, -0.4, 0.2], 0.5), (-0.2, [0.0, 1.5, 0.0], 2.0)],
        sh: vec![],
    });
    p.push(&PrimitiveInit {
        mean_m: [-0.1, 0.1, 2.6],
        scale_m: [0.3, 0.6, 0.2],
        quat: [0.7, -0.3, 0.5, 0.1],
        opacity: 0.6,
        beta: 2.0,
        omega_low: 0.2,
        // amplitude larger than ω_low: F's ReLU clips part of the primitive
        bands: vec![(0.5, [1.0, 0.0, 0.0], 0.0), (0.0, [0.0; 3], 0.0)],
        sh: vec![],
    });
    let out = render(&p, &cam, &RenderSettings::default()).unwrap();
    let mut both = 0;
    let mut clipped = 0;
    for y in 0..cam.height {
        for x in 0..cam.width {
            let px = y * cam.width + x;
            let front = brute(&p, 1, &cam, x, y);
            let back = brute(&p, 0, &cam, x, y);
            let mut want = [0.0f64; 6]; // thermal, low, high, beta, depth, alpha
            let mut trans = 1.0;
            for s in [front.as_ref(), back.as_ref()].into_iter().flatten() {
                let w = trans * s.alpha;
                for (k, v) in [s.f, s.low, s.high, s.beta, s.t, 1.0]
                    .into_iter()
                    .enumerate()
                {
                    want[k] += w * v;
                }
                trans *= 1.0 - s.alpha;
            }
            if front.is_some() && back.is_some() {
                both += 1;
            }
            if front.as_ref().is_some_and(|s| s.f == 0.0) {
                clipped += 1;
            }
            let got = [
                out.thermal[px],
                out.psi_low[px],
                out.psi_high[px],
                out.psi_beta[px],
                out.depth[px],
                out.alpha[px],
            ];
            for (k, name) in [
                "thermal", "psi_low", "psi_high", "psi_beta", "depth", "alpha",
            ]
            .iter()
            .enumerate()
            {
                assert!(
                    (got[k] - want[k]).abs() <= 1e-7 * (1.0 + want[k].abs()),
                    "{name} at ({x}, {y}): renderer {} vs brute force {}",
                    got[k],
                    want[k]
                );
            }
        }
    }
    assert!(
        both > 20,
        "the primitives must overlap on many pixels: {both}"
    );
    assert!(clipped > 0, "some pixels must exercise the ReLU of F");
}

#[test]
fn default_settings_point_sample_without_dilation() {
    // A primitive far smaller than a pixel, centred between pixel centres, is invisible (point
    // sampling, no low-pass dilation), while the same primitive on a pixel centre is seen with
    // α = o there.
    let cam = front_camera(8, 8, 8.0);
    for (u, want_visible) in [(3.5, false), (3.0, true)] {
        let mut p = Primitives::<f64>::new(0, None);
        p.push(&PrimitiveInit {
            mean_m: point_at_pixel(&cam, u, 3.0, 2.0),
            scale_m: [1e-3; 3],
            opacity: 0.5,
            ..PrimitiveInit::default()
        });
        let out = render(&p, &cam, &RenderSettings::default()).unwrap();
        let max_alpha = out.alpha.iter().cloned().fold(0.0, f64::max);
        if want_visible {
            assert!(
                (max_alpha - 0.5).abs() < 1e-9,
                "on a pixel centre α = o = 0.5, got {max_alpha}"
            );
        } else {
            assert_eq!(
                max_alpha, 0.0,
                "between pixel centres a 1e-3 m primitive is not sampled"
            );
        }
    }
}

#[test]
fn invalid_inputs_are_errors_naming_what_is_wrong() {
    let cam = front_camera(8, 8, 8.0);
    let p = Primitives::<f64>::new(0, Some(4));
    let err = render(&p, &cam, &RenderSettings::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("SH degree 4"),
        "unsupported SH degree must be named: {err}"
    );
    let mut p = Primitives::<f64>::new(2, None);
    p.push(&PrimitiveInit::default());
    p.band_phase.pop();
    let err = render(&p, &cam, &RenderSettings::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("band_phase"),
        "a short parameter group must be named: {err}"
    );
    let bad = PinholeCamera { fx_px: 0.0, ..cam };
    let err = render(
        &Primitives::<f64>::new(0, None),
        &bad,
        &RenderSettings::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("focal"),
        "a zero focal length must be rejected: {err}"
    );
}

#[test]
fn beta_parameterisation_round_trips_and_clamps() {
    use s3tir_trainer::primitive::{BETA_MAX, BETA_RAW_GAUSSIAN, beta_of_raw, beta_raw_from_beta};
    for beta in [2.001, 2.5, 3.0, 10.0, 40.0, 63.9] {
        let (back, d) = beta_of_raw(beta_raw_from_beta(beta));
        assert!((back - beta).abs() < 1e-9 * beta, "β {beta} → raw → {back}");
        assert!(d > 0.0, "below the clamp dβ/draw > 0, got {d} at β {beta}");
    }
    for beta in [BETA_MAX, 100.0] {
        let (back, d) = beta_of_raw(beta_raw_from_beta(beta));
        assert!(
            back == BETA_MAX && d == 0.0,
            "β {beta} must sit on the clamp: {back}, dβ/draw {d}"
        );
    }
    let (b2, _) = beta_of_raw(BETA_RAW_GAUSSIAN);
    assert!(
        b2 > 2.0 && b2 < 2.0 + 1e-4,
        "the Gaussian init gives β ≈ 2: {b2}"
    );
    let (never_below, _) = beta_of_raw(-1e6f64);
    assert_eq!(never_below, 2.0, "β can't go below 2");
}
