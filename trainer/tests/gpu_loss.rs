//! Proves the GPU single-view loss matches the CPU reference (`loss::view_loss`, f64) on
//! lavapipe: the four loss values (L1, SSIM, Ψ_high sparsity, Ψ_β TV) within 1e-5 relative, and
//! the upstream gradient planes (thermal from L1 + D-SSIM, Ψ_high, Ψ_β) within a relative L2
//! error of 1e-4 each, with the planes the single-view loss does not touch exactly zero. Inputs
//! include exact zeros (sign at 0), flat Ψ_β regions (the ε under the TV root) and odd image
//! sizes (zero padding of the SSIM window at the borders). With a view response
//! (`loss::response`: an AGC-like gain and offset, and a stiff gain of 0.05) the same, plus
//! `dL/dgain` and `dL/doffset` within 2e-5 of the sum of their per-pixel terms' magnitudes.
//! Does NOT cover the consistency term.
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_trainer::gpu::loss::GpuViewLoss;
use s3tir_trainer::gpu::{ContextOptions, DeviceChoice, GpuContext, MemoryLocation};
use s3tir_trainer::loss::response::{ViewResponse, view_loss_with_response};
use s3tir_trainer::loss::{LossWeights, view_loss};
use s3tir_trainer::render::GBuffers;

fn lavapipe() -> GpuContext {
    GpuContext::new(&ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics: false,
    })
    .expect("lavapipe (Mesa llvmpipe) must be available: install mesa-vulkan-drivers")
}

fn scene(seed: u64, w: usize, h: usize) -> (GBuffers<f64>, Vec<f64>) {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let mut g = GBuffers::zeros(w, h, false);
    let n = w * h;
    for p in 0..n {
        let (x, y) = (p % w, p / w);
        g.thermal[p] = 0.5
            + 0.4 * ((x as f64) * 0.3).sin() * ((y as f64) * 0.2).cos()
            + r.random_range(-0.05..0.05);
        g.psi_high[p] = if p % 5 == 0 {
            0.0
        } else {
            r.random_range(-0.2..0.4)
        };
        // Flat β = 2 on the left half, an edge, then noisy β on the right.
        g.psi_beta[p] = if x < w / 2 {
            2.0
        } else {
            6.0 + r.random_range(0.0..2.0)
        };
        g.psi_low[p] = r.random_range(0.0..1.0);
        g.depth[p] = r.random_range(0.0..3.0);
        g.alpha[p] = r.random_range(0.0..1.0);
    }
    let target = (0..n)
        .map(|p| {
            if p % 7 == 0 {
                g.thermal[p]
            } else {
                (g.thermal[p] + r.random_range(-0.2..0.2)).clamp(0.0, 1.0)
            }
        })
        .collect();
    (g, target)
}

fn planes_f32(g: &GBuffers<f64>) -> Vec<f32> {
    [
        &g.thermal,
        &g.psi_low,
        &g.psi_high,
        &g.psi_beta,
        &g.depth,
        &g.alpha,
    ]
    .iter()
    .flat_map(|v| v.iter().map(|x| *x as f32))
    .collect()
}

#[test]
fn gpu_view_loss_matches_cpu_values_and_gradients() {
    let ctx = lavapipe();
    let weights = LossWeights::default();
    let responses = [
        None,
        Some(ViewResponse {
            gain: 0.85,
            offset: 0.04,
            pivot: 0.48,
        }),
        Some(ViewResponse {
            gain: 0.05,
            offset: -0.1,
            pivot: 0.5,
        }),
    ];
    for (case, ((w, h), response)) in [(64usize, 48usize), (61, 47), (23, 90)]
        .into_iter()
        .flat_map(|size| responses.iter().map(move |r| (size, *r)))
        .enumerate()
    {
        let seed = case / responses.len();
        let (rendered, target) = scene(seed as u64, w, h);
        let npix = w * h;
        let mut want_up = GBuffers::zeros(w, h, false);
        let (want, want_resp) = match &response {
            None => (
                view_loss(&rendered, &target, &weights, &mut want_up).unwrap(),
                None,
            ),
            Some(r) => {
                let (l, g) =
                    view_loss_with_response(&rendered, &target, &weights, r, &mut want_up).unwrap();
                (l, Some(g))
            }
        };

        let loss = GpuViewLoss::new(&ctx, w, h).unwrap();
        let rbuf = ctx.upload("rendered", &planes_f32(&rendered)).unwrap();
        let tbuf = ctx
            .upload(
                "target",
                &target.iter().map(|v| *v as f32).collect::<Vec<_>>(),
            )
            .unwrap();
        let ubuf = ctx
            .create_buffer("upstream", (6 * npix * 4) as u64, MemoryLocation::Readback)
            .unwrap();
        ctx.submit(|rec| loss.record(rec, &rbuf, &tbuf, &ubuf, &weights, response.as_ref()))
            .unwrap();
        let got = loss.values(&ctx, response.is_some()).unwrap();
        let up: Vec<f32> = ctx.read(&ubuf, 6 * npix).unwrap();

        let label = format!("{w}x{h} response {response:?}");
        match (got.response, want_resp, &response) {
            (None, None, None) => {}
            (Some(g), Some(c), Some(r)) => {
                // Σ|u'|·|x − m| and Σ|u'|, u' = dL/d(responded value) = upstream / gain.
                let scale_gain: f64 = want_up
                    .thermal
                    .iter()
                    .zip(&rendered.thermal)
                    .map(|(u, x)| (u / r.gain).abs() * (x - r.pivot).abs())
                    .sum();
                let scale_offset: f64 = want_up.thermal.iter().map(|u| (u / r.gain).abs()).sum();
                for (name, a, b, scale) in [
                    ("dL/dgain", g.gain, c.gain, scale_gain),
                    ("dL/doffset", g.offset, c.offset, scale_offset),
                ] {
                    assert!(
                        (a - b).abs() <= 2e-5 * scale,
                        "{label}: {name} GPU {a}, CPU {b} (term magnitudes {scale})"
                    );
                }
            }
            other => panic!("{label}: response gradients present on one side only: {other:?}"),
        }
        for (name, g, c) in [
            ("l1", got.l1, want.l1),
            ("ssim", got.ssim, want.ssim),
            ("sparse", got.sparse, want.sparse),
            ("smooth", got.smooth, want.smooth),
        ] {
            assert!(
                (g - c).abs() <= 1e-5 * c.abs().max(1e-3),
                "{label}: {name} GPU {g}, CPU {c}"
            );
        }
        assert!(
            (got.total(&weights) - want.total).abs() <= 1e-5 * want.total.abs(),
            "{label}: total {} vs {}",
            got.total(&weights),
            want.total
        );

        let cpu_planes = [
            ("thermal", &want_up.thermal),
            ("psi_low", &want_up.psi_low),
            ("psi_high", &want_up.psi_high),
            ("psi_beta", &want_up.psi_beta),
            ("depth", &want_up.depth),
            ("alpha", &want_up.alpha),
        ];
        for ((name, c), g) in cpu_planes.into_iter().zip(up.chunks_exact(npix)) {
            let norm = c.iter().map(|v| v * v).sum::<f64>().sqrt();
            let err = g
                .iter()
                .zip(c.iter())
                .map(|(a, b)| (f64::from(*a) - b).powi(2))
                .sum::<f64>()
                .sqrt();
            if norm == 0.0 {
                assert!(
                    g.iter().all(|v| *v == 0.0),
                    "{label}/{name}: must be exactly zero"
                );
            } else {
                assert!(
                    err / norm <= 1e-4,
                    "{label}/{name}: relative L2 error {:.3e} > 1e-4",
                    err / norm
                );
            }
        }
        for b in [rbuf, tbuf, ubuf] {
            ctx.destroy_buffer(b);
        }
        loss.destroy(&ctx);
    }
}
