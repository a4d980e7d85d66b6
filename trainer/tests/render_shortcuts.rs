//! Proves the CPU reference renderer's shortcuts are exact: the cheap Gaussian path (β frozen at
//! exactly 2 via `BETA_RAW_FROZEN`: no `pow`, no β-gradient term) and skipping dropped band
//! slots (`band_count`) give bit-identical image and G-buffers, in f32 and f64, to the same
//! primitives forced through the general path (`Prepared::without_shortcuts`), and bit-identical
//! gradients for every live parameter, while dropped slots get exactly zero gradient; and the
//! analytic gradients of sets mixing frozen, general and partially dropped primitives still
//! match f64 central differences (a frozen β and a dropped slot have zero derivative in the
//! model too). Also checks that the frozen sentinel gives β = 2 and dβ/dbeta_raw = 0 exactly.
//! Does not measure the time saved (that is `benches/cpu_render.rs` and `capacity.json`).
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use s3tir_trainer::primitive::{BETA_RAW_FROZEN, Primitives, beta_of_raw};
use s3tir_trainer::real::Real;
use s3tir_trainer::render::{
    GBuffers, RenderSettings, prepare, render_backward_prepared, render_prepared,
};

const M: usize = 3;

/// Six primitives: 0–1 frozen Gaussians with no band, 2 frozen with one live band, 3 general
/// β with one of three bands live, 4 general with all bands, 5 general with none.
fn scene() -> Primitives<f64> {
    let mut r = rng(7);
    let mut p = Primitives::new(M, Some(1));
    let k = p.sh_k();
    let betas = [2.0, 2.0, 2.0, 3.5, 6.0, 2.4];
    for &beta in &betas {
        p.push(&random_primitive(&mut r, [0.0, 0.0, 3.0], beta, M, k));
    }
    let live = [0u32, 0, 1, 1, 3, 0];
    for (i, &c) in live.iter().enumerate() {
        p.band_count[i] = c;
        // Dropped slots hold zeros (what the trainer guarantees).
        for j in c as usize..M {
            let s = M * i + j;
            p.band_amp[s] = 0.0;
            p.band_phase[s] = 0.0;
            p.band_freq[3 * s..3 * s + 3].fill(0.0);
        }
    }
    for i in 0..3 {
        p.beta_raw[i] = BETA_RAW_FROZEN;
    }
    p
}

fn check_exact<T: Real>(name: &str) {
    let prims = scene().cast::<T>();
    let cam = front_camera(24, 20, 22.0);
    let prep = prepare(&prims, &cam, &RenderSettings::default()).unwrap();
    assert!(
        (0..3).all(|i| prep.prims[i].gaussian) && (3..6).all(|i| !prep.prims[i].gaussian),
        "{name}: frozen primitives (and only those) take the Gaussian path"
    );
    let general = prep.without_shortcuts(M);
    let a = render_prepared(&prims, &prep);
    let b = render_prepared(&prims, &general);
    assert!(
        a.alpha.iter().any(|x| x.to_f64() > 0.1),
        "{name}: scene is visible"
    );
    for ((n, x), (_, y)) in a.planes().iter().zip(b.planes()) {
        let diff = x.iter().zip(y.iter()).filter(|(p, q)| p != q).count();
        assert_eq!(
            diff, 0,
            "{name}: {n}: {diff} pixels differ from the general path"
        );
    }
    let mut up = GBuffers::<T>::zeros(a.width, a.height, true);
    let mut r = rng(3);
    let rnd = random_upstream::<T>(&mut r, &a);
    up.planes_mut()
        .into_iter()
        .zip(rnd.planes())
        .for_each(|((_, d), (_, s))| d.clone_from(s));
    let ga = render_backward_prepared(&prims, &prep, &up);
    let gb = render_backward_prepared(&prims, &general, &up);
    for ((n, x), (_, y)) in ga.groups().iter().zip(gb.groups()) {
        for (k, (p, q)) in x.iter().zip(y.iter()).enumerate() {
            let dropped = match n.per_band_slot() {
                Some(per) => (k / per) % M >= prims.live_bands(k / per / M),
                None => false,
            };
            if dropped {
                assert!(
                    *p == T::ZERO,
                    "{name}: dropped slot {n}[{k}] has gradient {}",
                    p.to_f64()
                );
            } else {
                assert!(
                    p == q,
                    "{name}: {n}[{k}] shortcut {} vs general {}",
                    p.to_f64(),
                    q.to_f64()
                );
            }
        }
    }
    for i in 0..3 {
        assert!(
            ga.beta_raw[i] == T::ZERO,
            "{name}: frozen β {i} gets no gradient"
        );
    }
    assert!(
        (3..6).any(|i| ga.beta_raw[i] != T::ZERO),
        "{name}: learnable β still gets gradients"
    );
}

#[test]
fn frozen_sentinel_is_exactly_two_with_zero_derivative() {
    let (b64, d64) = beta_of_raw(BETA_RAW_FROZEN);
    let (b32, d32) = beta_of_raw(BETA_RAW_FROZEN as f32);
    assert_eq!((b64, d64), (2.0, 0.0), "f64 β, dβ/draw");
    assert_eq!((b32, d32), (2.0f32, 0.0f32), "f32 β, dβ/draw");
}

#[test]
fn shortcuts_are_bit_identical_to_the_general_path_f64() {
    check_exact::<f64>("f64");
}

#[test]
fn shortcuts_are_bit_identical_to_the_general_path_f32() {
    check_exact::<f32>("f32");
}

#[test]
fn gradients_with_frozen_and_dropped_match_finite_differences() {
    let prims = scene();
    let cam = front_camera(24, 20, 22.0);
    let (fails, checked) = check_render_gradient(
        &prims,
        &cam,
        &RenderSettings::default(),
        5,
        1e-6,
        1e-6,
        1e-5,
    );
    assert!(checked > 100, "checked {checked} entries");
    assert!(
        fails.is_empty(),
        "{} of {checked} gradient entries disagree with central differences \
         (group, index, analytic, numeric): {:?}",
        fails.len(),
        &fails[..fails.len().min(12)]
    );
}
