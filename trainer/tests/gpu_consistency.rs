//! Proves the GPU consistency term (`gpu::consistency`) matches the CPU reference
//! (`loss::consistency::consistency_loss`, f64 on the same f32 inputs) on lavapipe, with float
//! atomics and with the compare-and-swap fallback forced: the same number of unmasked pixels
//! (±0.1 %), the loss within 1e-4 relative, and the upstream planes it adds to (Ψ_high, Ψ_β of
//! both views) within a relative L2 error of 1e-3, the other planes untouched. The two views see
//! a textured ground plane from different poses, with a low-alpha patch (no depth: masked), an
//! occluder in the source view (masked by the depth test) and pixels that leave the source image.
//! Does NOT cover the term inside the training loop (the loop still computes it on the host).
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::gpu::accumulate::AccumulateVariant;
use s3tir_trainer::gpu::consistency::{ConsistencyViews, GpuConsistency};
use s3tir_trainer::gpu::raster::camera_block;
use s3tir_trainer::gpu::{ContextOptions, DeviceChoice, GpuContext};
use s3tir_trainer::loss::consistency::{ConsistencyOptions, consistency_loss};
use s3tir_trainer::render::{GBuffers, RenderSettings};

fn lavapipe_with(disable_float_atomics: bool) -> GpuContext {
    GpuContext::new(&ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics,
    })
    .expect("lavapipe (Mesa llvmpipe) must be available: install mesa-vulkan-drivers")
}

/// G-buffers of the ground plane z = 0 seen by `cam`: expected depth from the ray, alpha near 1
/// except a low-alpha patch, Ψ from smooth world-space fields plus noise; `occluder` pulls a
/// rectangle's depth 30 % closer. Values are f32-representable.
fn view(cam: &PinholeCamera, seed: u64, occluder: Option<[usize; 4]>) -> GBuffers<f64> {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let (w, h) = (cam.width, cam.height);
    let mut g = GBuffers::zeros(w, h, false);
    let wm = cam.pixel_to_world_dir();
    let c = cam.centre_world();
    let f32r = |v: f64| f64::from(v as f32);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let d =
                [0, 1, 2].map(|k| wm[3 * k] * x as f64 + wm[3 * k + 1] * y as f64 + wm[3 * k + 2]);
            let mut depth = -c[2] / d[2];
            let world = [c[0] + depth * d[0], c[1] + depth * d[1]];
            if let Some([x0, y0, x1, y1]) = occluder
                && (x0..x1).contains(&x)
                && (y0..y1).contains(&y)
            {
                depth *= 0.7;
            }
            let patch = (world[0] - 0.2).hypot(world[1] + 0.1) < 0.15;
            let alpha = if patch {
                r.random_range(0.0..0.4)
            } else {
                r.random_range(0.9..1.0)
            };
            g.alpha[p] = f32r(alpha);
            g.depth[p] = f32r(depth * alpha);
            g.psi_high[p] = f32r(
                0.3 + 0.2 * (7.0 * world[0]).sin() * (5.0 * world[1]).cos()
                    + r.random_range(-0.05..0.05),
            );
            g.psi_beta[p] = f32r(
                2.0 + 4.0 * (3.0 * world[0] + 2.0 * world[1]).cos().abs()
                    + r.random_range(0.0..0.5),
            );
            g.thermal[p] = f32r(r.random_range(0.0..1.0));
            g.psi_low[p] = f32r(r.random_range(0.0..1.0));
        }
    }
    g
}

/// Upstream planes that already hold something (the term adds to them).
fn upstream(w: usize, h: usize, seed: u64) -> GBuffers<f64> {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let mut g = GBuffers::zeros(w, h, false);
    for plane in [
        &mut g.thermal,
        &mut g.psi_low,
        &mut g.psi_high,
        &mut g.psi_beta,
        &mut g.depth,
        &mut g.alpha,
    ] {
        for v in plane.iter_mut() {
            *v = f64::from(r.random_range(-1e-3f32..1e-3));
        }
    }
    g
}

fn planes(g: &GBuffers<f64>, count: usize) -> Vec<f32> {
    let mut out: Vec<f32> = [
        &g.thermal,
        &g.psi_low,
        &g.psi_high,
        &g.psi_beta,
        &g.depth,
        &g.alpha,
    ]
    .iter()
    .flat_map(|v| v.iter().map(|x| *x as f32))
    .collect();
    out.resize(count * g.width * g.height, 0.0);
    out
}

fn compare_plane(label: &str, got: &[f32], want: &[f64], touched: bool) {
    assert_eq!(got.len(), want.len(), "{label}: length");
    let err = got
        .iter()
        .zip(want)
        .map(|(a, b)| (f64::from(*a) - b).powi(2))
        .sum::<f64>()
        .sqrt();
    let norm = want.iter().map(|v| v * v).sum::<f64>().sqrt();
    let bound = if touched { 1e-3 } else { 1e-7 };
    assert!(
        err <= bound * norm,
        "{label}: relative L2 error {:.3e}, expected <= {bound:e} ({})",
        err / norm,
        if touched {
            "a plane the term adds to"
        } else {
            "a plane the term must not touch"
        }
    );
}

#[test]
fn gpu_consistency_matches_cpu_reference_with_and_without_float_atomics() {
    let (wi, hi, wj, hj) = (61usize, 47usize, 64usize, 48usize);
    let cam_i = PinholeCamera::look_at(
        [0.1, -0.05, -1.6],
        [0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        70.0,
        wi,
        hi,
    );
    let cam_j = PinholeCamera::look_at(
        [0.45, 0.1, -1.7],
        [0.05, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        75.0,
        wj,
        hj,
    );
    let view_i = view(&cam_i, 1, None);
    let view_j = view(&cam_j, 2, Some([20, 10, 34, 22]));
    let opt = ConsistencyOptions::default();
    let weight = 0.37;
    let (up_i0, up_j0) = (upstream(wi, hi, 3), upstream(wj, hj, 4));
    let (mut want_i, mut want_j) = (up_i0.clone(), up_j0.clone());
    let want = consistency_loss(
        &view_i,
        &cam_i,
        &view_j,
        &cam_j,
        &opt,
        weight,
        &mut want_i,
        &mut want_j,
    )
    .unwrap();
    let npix_i = wi * hi;
    assert!(
        want.valid_px > npix_i / 3 && want.valid_px < npix_i - 100,
        "the scene must mix valid and masked pixels: {} of {npix_i} valid",
        want.valid_px
    );

    for disable_float_atomics in [false, true] {
        let ctx = lavapipe_with(disable_float_atomics);
        let variant = AccumulateVariant::best_for(ctx.capabilities());
        let term = GpuConsistency::new(&ctx, variant, wi, hi).unwrap();
        let settings = RenderSettings::default();
        let bufs = [
            ctx.upload("test.cam_i", &camera_block(&cam_i, &settings))
                .unwrap(),
            ctx.upload("test.cam_j", &camera_block(&cam_j, &settings))
                .unwrap(),
            ctx.upload("test.planes_i", &planes(&view_i, 7)).unwrap(),
            ctx.upload("test.planes_j", &planes(&view_j, 7)).unwrap(),
            ctx.upload("test.up_i", &planes(&up_i0, 6)).unwrap(),
            ctx.upload("test.up_j", &planes(&up_j0, 6)).unwrap(),
        ];
        let views = ConsistencyViews {
            cam_i: &bufs[0],
            cam_j: &bufs[1],
            planes_i: &bufs[2],
            planes_j: &bufs[3],
            up_i: &bufs[4],
            up_j: Some(&bufs[5]),
            width_j: wj,
            height_j: hj,
        };
        ctx.submit(|rec| term.record(rec, &views, &opt, weight as f32))
            .unwrap();
        let got = term.values(&ctx).unwrap();
        let label = format!("{variant:?}");
        let slack = (want.valid_px / 1000).max(1);
        assert!(
            got.valid_px.abs_diff(want.valid_px) <= slack,
            "{label}: {} valid pixels, the CPU reference has {} (allowed ±{slack})",
            got.valid_px,
            want.valid_px
        );
        assert!(
            (got.loss - want.loss).abs() <= 1e-4 * want.loss,
            "{label}: loss {} vs CPU {} (relative 1e-4)",
            got.loss,
            want.loss
        );
        let up_i: Vec<f32> = ctx.read(&bufs[4], 6 * npix_i).unwrap();
        let up_j: Vec<f32> = ctx.read(&bufs[5], 6 * wj * hj).unwrap();
        for (view, got_planes, want_planes, n) in [
            ("view i", &up_i, &want_i, npix_i),
            ("view j", &up_j, &want_j, wj * hj),
        ] {
            let named = [
                ("thermal", &want_planes.thermal, false),
                ("psi_low", &want_planes.psi_low, false),
                ("psi_high", &want_planes.psi_high, true),
                ("psi_beta", &want_planes.psi_beta, true),
                ("depth", &want_planes.depth, false),
                ("alpha", &want_planes.alpha, false),
            ];
            for (k, (name, want_plane, touched)) in named.into_iter().enumerate() {
                compare_plane(
                    &format!("{label}, {view} upstream {name}"),
                    &got_planes[k * n..(k + 1) * n],
                    want_plane,
                    touched,
                );
            }
        }
        // Stop-gradient on view j (its planes kept from an earlier step, `up_j` None): the same
        // loss and view i upstream, view j's upstream buffer untouched.
        let up_i_sg = ctx.upload("test.up_i_sg", &planes(&up_i0, 6)).unwrap();
        let views_sg = ConsistencyViews {
            up_i: &up_i_sg,
            up_j: None,
            ..views
        };
        ctx.submit(|rec| term.record(rec, &views_sg, &opt, weight as f32))
            .unwrap();
        let got_sg = term.values(&ctx).unwrap();
        assert_eq!(
            (got_sg.loss, got_sg.valid_px),
            (got.loss, got.valid_px),
            "{label}: the term without gradient to view j must have the same value"
        );
        let up_i_after: Vec<f32> = ctx.read(&up_i_sg, 6 * npix_i).unwrap();
        assert!(
            up_i_after == up_i,
            "{label}: view i's upstream must not depend on view j's stop-gradient"
        );
        let up_j_after: Vec<f32> = ctx.read(&bufs[5], 6 * wj * hj).unwrap();
        assert!(
            up_j_after == up_j,
            "{label}: view j's upstream must be untouched under stop-gradient"
        );
        ctx.destroy_buffer(up_i_sg);
        for b in bufs {
            ctx.destroy_buffer(b);
        }
        term.destroy(&ctx);
        assert_eq!(
            ctx.allocated_bytes(),
            0,
            "{label}: every GPU buffer must be released"
        );
    }
}
