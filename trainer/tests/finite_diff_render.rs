//! Proves: the analytic backward pass of the CPU reference renderer equals central finite
//! differences (f64) of a random linear functional of **every** output buffer (thermal image, RGB,
//! Ψ_low, Ψ_high, Ψ_β, depth, alpha) w.r.t. **every** parameter kind (μ, log-scales, quaternion,
//! opacity logit, β, ω_low, ω_j, f_j, φ_j, SH colour), for β near 2, β large, and pixels at and near
//! a primitive's centre (m → 0), and that β on its clamp gets an exactly zero, finite gradient.
//! Does NOT prove: that the forward pass is the right model (see the culling, Fig. 3 and stiff
//! suites), or behaviour at the non-differentiable points (α cut at 1/255, early stop, α clamp,
//! ReLU kinks) — the scenes keep away from them.
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use s3tir_trainer::primitive::{BETA_MAX, PrimitiveInit, Primitives};
use s3tir_trainer::render::{RenderSettings, render, render_backward};

fn scene(seed: u64, betas: &[f64], bands: usize, sh_degree: Option<usize>) -> Primitives<f64> {
    let mut r = rng(seed);
    let mut p = Primitives::new(bands, sh_degree);
    let k = p.sh_k();
    for &beta in betas {
        let init = random_primitive(&mut r, [0.0, 0.0, 3.0], beta, bands, k);
        p.push(&init);
    }
    p
}

fn assert_gradients(name: &str, prims: &Primitives<f64>, seed: u64) {
    let cam = front_camera(24, 20, 22.0);
    let settings = RenderSettings::default();
    let (fails, checked) = check_render_gradient(prims, &cam, &settings, seed, 1e-6, 1e-6, 1e-5);
    assert!(checked > 0);
    assert!(
        fails.is_empty(),
        "{name}: {} of {checked} gradient entries disagree with central differences \
         (group, index, analytic, numeric): {:?}",
        fails.len(),
        &fails[..fails.len().min(12)]
    );
}

#[test]
fn gradients_match_finite_differences_beta_near_two() {
    let prims = scene(1, &[2.0, 2.0, 2.0001, 2.01], 2, Some(1));
    assert_gradients("beta≈2", &prims, 11);
}

#[test]
fn gradients_match_finite_differences_beta_large() {
    let prims = scene(2, &[8.0, 20.0, 40.0], 2, Some(0));
    assert_gradients("beta large", &prims, 12);
}

#[test]
fn gradients_match_finite_differences_all_sh_degrees_and_no_bands() {
    for (deg, bands) in [(None, 0usize), (Some(2), 1), (Some(3), 4)] {
        let prims = scene(3 + bands as u64, &[2.5, 3.5], bands, deg);
        assert_gradients(&format!("sh {deg:?}, M = {bands}"), &prims, 13);
    }
}

#[test]
fn gradients_match_finite_differences_at_and_near_centre() {
    // One primitive centred exactly on the ray of pixel (12, 10) (m = 0 there) and one 1e-4 px off
    // a pixel ray (m → 0), for β just above 2 and β large.
    let cam = front_camera(24, 20, 22.0);
    for beta in [2.0, 2.001, 3.0, 16.0] {
        let mut prims = Primitives::<f64>::new(1, None);
        prims.push(&PrimitiveInit {
            mean_m: point_at_pixel(&cam, 12.0, 10.0, 3.0),
            scale_m: [0.3, 0.2, 0.4],
            quat: [0.9, 0.1, -0.2, 0.3],
            opacity: 0.6,
            beta,
            omega_low: 0.7,
            bands: vec![(0.1, [0.3, -0.2, 0.5], 0.4)],
            sh: vec![],
        });
        prims.push(&PrimitiveInit {
            mean_m: point_at_pixel(&cam, 6.0 + 1e-4, 5.0, 2.5),
            scale_m: [0.25, 0.25, 0.25],
            opacity: 0.5,
            beta,
            omega_low: 0.3,
            bands: vec![(-0.1, [0.0, 0.4, 0.0], 1.0)],
            ..PrimitiveInit::default()
        });
        assert_gradients(&format!("m→0, β = {beta}"), &prims, 14);
    }
}

#[test]
fn beta_on_its_clamp_has_zero_finite_gradient() {
    let mut prims = scene(5, &[BETA_MAX, 200.0], 1, None);
    prims.beta_raw[1] = 500.0;
    let cam = front_camera(24, 20, 22.0);
    let settings = RenderSettings::default();
    let out = render(&prims, &cam, &settings).unwrap();
    let up = random_upstream(&mut rng(6), &out);
    let g = render_backward(&prims, &cam, &settings, &up).unwrap();
    for (i, gb) in g.beta_raw.iter().enumerate() {
        assert!(
            *gb == 0.0,
            "β of primitive {i} is on the clamp: want dL/dbeta_raw = 0, got {gb}"
        );
    }
    let psi_beta_max = out.psi_beta.iter().cloned().fold(0.0, f64::max);
    assert!(
        psi_beta_max <= BETA_MAX + 1e-9,
        "Ψ_β can't exceed the clamp {BETA_MAX}: max {psi_beta_max}"
    );
    assert!(
        g.groups()
            .iter()
            .all(|(_, v)| v.iter().all(|x| x.is_finite())),
        "non-finite gradient on the β clamp"
    );
}
