//! Proves: tile culling with the β = 2 bounding Gaussian (radius max(1, √ln(255·o)), exact conic
//! silhouette) never drops a sample with α ≥ 1/255: (1) by brute force over randomised primitives
//! (random positions, needle-to-pancake scales, rotations, opacities and β ∈ [2, 64]) every pixel
//! where a primitive contributes lies in a tile that lists it, and (2) the culled render equals the
//! unculled render bit for bit, in f64 and f32.
//! Does NOT prove: that the boxes are tight (only that they contain), or anything about speed.
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use rand::Rng;
use s3tir_trainer::primitive::{BETA_MAX, PrimitiveInit, Primitives};
use s3tir_trainer::real::Real;
use s3tir_trainer::render::{ALPHA_MAX, ALPHA_MIN, RenderSettings, TILE_SIZE, prepare, render};

fn random_scene(seed: u64, n: usize) -> Primitives<f64> {
    let mut r = rng(seed);
    let mut p = Primitives::new(1, None);
    for i in 0..n {
        let beta = match i % 4 {
            0 => 2.0,
            1 => BETA_MAX,
            _ => r.random_range(2.0..BETA_MAX),
        };
        let base = r.random_range(0.02..0.5f64);
        let aniso = |r: &mut rand_chacha::ChaCha8Rng| base * 10f64.powf(r.random_range(-1.5..1.0));
        p.push(&PrimitiveInit {
            mean_m: [
                r.random_range(-2.0..2.0),
                r.random_range(-1.5..1.5),
                r.random_range(0.3..6.0),
            ],
            scale_m: [aniso(&mut r), aniso(&mut r), aniso(&mut r)],
            quat: random_quat(&mut r),
            opacity: 10f64.powf(r.random_range(-2.5..0.0)),
            beta,
            omega_low: r.random_range(0.1..1.0),
            bands: vec![(0.1, [0.5, 0.2, -0.3], 0.3)],
            sh: vec![],
        });
    }
    p
}

/// α of primitive `i` at pixel (x, y), straight from the definition (no culling involved).
fn brute_alpha(
    p: &Primitives<f64>,
    cam: &s3tir_trainer::camera::PinholeCamera,
    i: usize,
    x: usize,
    y: usize,
) -> Option<f64> {
    let c = cam.centre_world();
    let o_world = cam.unproject(x as f64, y as f64, 0.0);
    let e = cam.unproject(x as f64, y as f64, 1.0);
    let d = [e[0] - o_world[0], e[1] - o_world[1], e[2] - o_world[2]];
    let mu = p.mean(i);
    let (rot, _, _) = s3tir_trainer::primitive::rotation_from_quat(p.quat(i));
    let s = p.scales(i);
    // whitened: N = diag(1/s) Rᵀ
    let whiten = |v: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|r| (rot[r] * v[0] + rot[3 + r] * v[1] + rot[6 + r] * v[2]) / s[r])
    };
    let a = whiten([c[0] - mu[0], c[1] - mu[1], c[2] - mu[2]]);
    let b = whiten(d);
    let bb: f64 = b.iter().map(|v| v * v).sum();
    let t = -(a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / bb;
    if t <= RenderSettings::default().near_m {
        return None;
    }
    let q: f64 = (0..3).map(|k| (a[k] + t * b[k]).powi(2)).sum();
    let (beta, _) = p.beta(i);
    let (o, _) = p.opacity(i);
    Some((o * (-q.powf(beta / 2.0)).exp()).min(ALPHA_MAX))
}

#[test]
fn every_contributing_pixel_is_in_a_listed_tile() {
    let cam = front_camera(80, 64, 60.0);
    let settings = RenderSettings::default();
    let mut contributing = 0usize;
    let mut tight = 0usize;
    for seed in 0..4u64 {
        let prims = random_scene(100 + seed, 120);
        let prep = prepare(&prims, &cam, &settings).unwrap();
        for i in 0..prims.len() {
            if !prep.prims[i].visible {
                continue;
            }
            for y in 0..cam.height {
                for x in 0..cam.width {
                    let Some(alpha) = brute_alpha(&prims, &cam, i, x, y) else {
                        continue;
                    };
                    if alpha < ALPHA_MIN {
                        continue;
                    }
                    contributing += 1;
                    let listed = prep.tile_lists[prep.tile_of(x, y)].contains(&(i as u32));
                    let [u0, v0, u1, v1] = prep.prims[i].bbox_px;
                    assert!(
                        listed,
                        "seed {seed}: primitive {i} has α = {alpha} ≥ 1/255 at pixel ({x}, {y}) but its \
                         tile ({}, {}) does not list it; box {:?}",
                        x / TILE_SIZE,
                        y / TILE_SIZE,
                        prep.prims[i].bbox_px
                    );
                    // how close to the box edge the contributions reach (the bound is not slack)
                    let margin = (x as f64 - u0)
                        .min(u1 - x as f64)
                        .min(y as f64 - v0)
                        .min(v1 - y as f64);
                    if margin < 3.0 {
                        tight += 1;
                    }
                }
            }
        }
    }
    assert!(
        contributing > 10_000,
        "the scenes must contribute to many pixels: {contributing}"
    );
    assert!(
        tight > 0,
        "no contribution reached within 3 px of a box edge: the test would miss a too-small box"
    );
}

fn assert_culled_equals_unculled<T: Real>(prims: &Primitives<T>) {
    let cam = front_camera(72, 56, 50.0);
    let culled = render(prims, &cam, &RenderSettings::default()).unwrap();
    let unculled = render(
        prims,
        &cam,
        &RenderSettings {
            cull: false,
            ..RenderSettings::default()
        },
    )
    .unwrap();
    for ((name, a), (_, b)) in culled.planes().iter().zip(unculled.planes().iter()) {
        for (k, (x, y)) in a.iter().zip(b.iter()).enumerate() {
            assert!(
                x.to_f64() == y.to_f64(),
                "{name}[{k}]: culled {x} vs unculled {y} ({})",
                std::any::type_name::<T>()
            );
        }
    }
    let covered = culled.alpha.iter().filter(|a| a.to_f64() > 0.0).count();
    assert!(
        covered > culled.alpha.len() / 4,
        "scene too sparse to test culling: {covered} px covered"
    );
}

#[test]
fn culled_render_equals_unculled_render() {
    for seed in 0..3u64 {
        let prims = random_scene(200 + seed, 150);
        assert_culled_equals_unculled(&prims);
        assert_culled_equals_unculled(&prims.cast::<f32>());
    }
}
