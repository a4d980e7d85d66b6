//! Proves: every loss term's analytic gradient equals central finite differences (f64):
//! L1 + D-SSIM and TGA-GS's L1-low + D-SSIM w.r.t. the image (and through the joint runs'
//! RGB background compositing w.r.t. the RGB, alpha and background colour), L1 sparsity w.r.t. Ψ_high, isotropic TV w.r.t. Ψ_β, the
//! multi-view consistency loss w.r.t. Ψ_high and Ψ_β of both views (depths and cameras held
//! fixed — the warp is under stop-gradient by design), and end to end: the single-view loss of
//! eq. 6 pushed through the renderer's backward pass w.r.t. every primitive parameter.
//! Also proves the consistency mask keeps co-visible pixels and drops occluded/out-of-view ones.
//! Does NOT prove: that the SSIM constants match a particular reference implementation
//! bit for bit, or gradients at the L1 kinks (inputs stay away from ties).
#![allow(clippy::unwrap_used)]

mod common;

use common::*;
use rand::Rng;
use s3tir_trainer::loss::consistency::{ConsistencyOptions, consistency_loss};
use s3tir_trainer::loss::photometric::{l1_dssim, l1_low_dssim};
use s3tir_trainer::loss::regularizers::{l1_sparsity, tv_isotropic};
use s3tir_trainer::loss::{LossWeights, view_loss};
use s3tir_trainer::primitive::Primitives;
use s3tir_trainer::render::{GBuffers, RenderSettings, render, render_backward};

const H: f64 = 1e-6;

/// Central differences of `f` at `x` vs `analytic`; panics naming the first mismatch.
fn assert_fd(
    name: &str,
    x: &[f64],
    analytic: &[f64],
    f: impl Fn(&[f64]) -> f64,
    atol: f64,
    rtol: f64,
) {
    assert_eq!(x.len(), analytic.len());
    let mut worst = (0usize, 0.0f64, 0.0f64, 0.0f64);
    let mut nonzero = 0;
    for k in 0..x.len() {
        let mut p = x.to_vec();
        p[k] += H;
        let mut m = x.to_vec();
        m[k] -= H;
        let numeric = (f(&p) - f(&m)) / (2.0 * H);
        let a = analytic[k];
        if a.abs() > 1e-9 {
            nonzero += 1;
        }
        let excess = (a - numeric).abs() - (atol + rtol * a.abs().max(numeric.abs()));
        if excess > worst.3 || !a.is_finite() {
            worst = (k, a, numeric, excess.max(f64::MIN_POSITIVE));
        }
    }
    assert!(
        worst.3 <= 0.0,
        "{name}: entry {} analytic {} vs central difference {} (tolerance {atol} + {rtol}·max)",
        worst.0,
        worst.1,
        worst.2
    );
    assert!(
        nonzero > 0,
        "{name}: gradient is identically zero, the check proves nothing"
    );
}

#[test]
fn l1_dssim_gradient_matches_finite_differences() {
    let (w, h) = (17, 13);
    let img = random_plane(1, w * h, 0.0, 1.0);
    let tgt = random_plane(2, w * h, 0.0, 1.0);
    let mut g = vec![0.0; w * h];
    let r = l1_dssim(&img, &tgt, w, h, 0.2, 1.0, &mut g).unwrap();
    assert!(
        r.ssim > -1.0 && r.ssim < 1.0,
        "SSIM of unrelated images in (−1, 1): {}",
        r.ssim
    );
    let f = |x: &[f64]| {
        let mut scratch = vec![0.0; w * h];
        l1_dssim(x, &tgt, w, h, 0.2, 1.0, &mut scratch)
            .unwrap()
            .loss
    };
    assert_fd("L1 + D-SSIM", &img, &g, f, 1e-8, 1e-5);
    // Identical images: SSIM exactly 1 and L1 = 0.
    let mut g2 = vec![0.0; w * h];
    let same = l1_dssim(&tgt, &tgt, w, h, 0.2, 1.0, &mut g2).unwrap();
    assert!(
        (same.ssim - 1.0).abs() < 1e-12 && same.l1 == 0.0,
        "self-SSIM {} L1 {}",
        same.ssim,
        same.l1
    );
}

/// L1-low on dark images (values 0.005–0.15, as a 2 %-exposure camera records): its gradient
/// matches central differences, weighs a dark pixel's residual far above a bright one's, and a
/// rendered 0 (the SH colour's clamp) gets no gradient.
#[test]
fn l1_low_gradient_matches_finite_differences_and_weighs_dark_pixels() {
    let (w, h) = (17, 13);
    let eps = 1e-3;
    let img = random_plane(3, w * h, 0.005, 0.15);
    let tgt = random_plane(4, w * h, 0.005, 0.15);
    let mut g = vec![0.0; w * h];
    l1_low_dssim(&img, &tgt, w, h, 0.2, eps, 1.0, &mut g).unwrap();
    let f = |x: &[f64]| {
        let mut scratch = vec![0.0; w * h];
        l1_low_dssim(x, &tgt, w, h, 0.2, eps, 1.0, &mut scratch)
            .unwrap()
            .loss
    };
    assert_fd("L1-low + D-SSIM", &img, &g, f, 1e-8, 1e-5);
    // Without SSIM: a residual of 0.01 at brightness 0.02 pulls ~(0.5+ε)/(0.02+ε) ≈ 22× harder
    // than the same residual at 0.5 (L1 pulls both alike).
    let img = [0.02, 0.5, 0.0];
    let tgt = [0.03, 0.51, 0.2];
    let mut g = [0.0; 3];
    let r = l1_low_dssim(&img, &tgt, 3, 1, 0.0, eps, 1.0, &mut g).unwrap();
    let ratio = g[0] / g[1];
    assert!(
        (ratio - 0.501f64 / 0.021).abs() < 1e-9,
        "dark/bright gradient ratio {ratio}, expected (0.5 + ε)/(0.02 + ε) = {}",
        0.501 / 0.021
    );
    assert!(
        g[0] < 0.0,
        "a render darker than its target is pulled up: {}",
        g[0]
    );
    assert_eq!(g[2], 0.0, "a rendered 0 (clamped colour) gets no gradient");
    // Scaled by the target's mean + ε (module docs: L1's size on a typical pixel).
    let norm = (0.03 + 0.51 + 0.2) / 3.0 + eps;
    let expect = norm
        * ((0.021f64 / 0.031).ln().abs()
            + (0.501f64 / 0.511).ln().abs()
            + (0.001f64 / 0.201).ln().abs())
        / 3.0;
    assert!(
        (r.l1 - expect).abs() < 1e-12,
        "L1-low {} vs (C̄ + ε)·mean |ln(Ĉ+ε) − ln(C+ε)| {expect}",
        r.l1
    );
}

/// The RGB views' background compositing (`shown = rgb + (1 − alpha)·bg`, joint runs) chained
/// into L1-low + D-SSIM: the gradients w.r.t. the rendered RGB, the alpha G-buffer and the
/// background colour match central differences.
#[test]
fn background_compositing_gradients_match_finite_differences() {
    use s3tir_trainer::train::{composite_background, composite_background_backward};
    let (w, h) = (9, 7);
    let n = w * h;
    let rgb = random_plane(5, 3 * n, 0.01, 0.2);
    let alpha = random_plane(6, n, 0.05, 0.95);
    let tgt = random_plane(7, 3 * n, 0.01, 0.3);
    let bg = [0.07, 0.12, 0.2];
    let loss = |rgb: &[f64], alpha: &[f64], bg: [f64; 3], grad: Option<&mut Vec<f64>>| {
        let shown = composite_background(rgb, alpha, bg);
        let mut g = vec![0.0; 3 * n];
        let mut total = 0.0;
        for c in 0..3 {
            total += l1_low_dssim(
                &shown[c * n..(c + 1) * n],
                &tgt[c * n..(c + 1) * n],
                w,
                h,
                0.2,
                1e-3,
                1.0 / 3.0,
                &mut g[c * n..(c + 1) * n],
            )
            .unwrap()
            .loss
                / 3.0;
        }
        if let Some(out) = grad {
            *out = g;
        }
        total
    };
    let mut g_shown = Vec::new();
    loss(&rgb, &alpha, bg, Some(&mut g_shown));
    let mut g_rgb = vec![0.0; 3 * n];
    let mut g_alpha = vec![0.0; n];
    let g_bg = composite_background_backward(&g_shown, &alpha, bg, &mut g_rgb, &mut g_alpha);
    assert_fd(
        "composite: rgb",
        &rgb,
        &g_rgb,
        |x| loss(x, &alpha, bg, None),
        1e-8,
        1e-5,
    );
    assert_fd(
        "composite: alpha",
        &alpha,
        &g_alpha,
        |x| loss(&rgb, x, bg, None),
        1e-8,
        1e-5,
    );
    assert_fd(
        "composite: background",
        &bg,
        &g_bg,
        |x| loss(&rgb, &alpha, [x[0], x[1], x[2]], None),
        1e-8,
        1e-5,
    );
}

#[test]
fn sparsity_and_tv_gradients_match_finite_differences() {
    let (w, h) = (9, 7);
    let psi = random_plane(3, w * h, 0.05, 1.0);
    let mut g = vec![0.0; w * h];
    l1_sparsity(&psi, 0.7, &mut g);
    assert_fd(
        "L_sparse",
        &psi,
        &g,
        |x| 0.7 * l1_sparsity(x, 1.0, &mut vec![0.0; w * h]),
        1e-9,
        1e-6,
    );

    let mut beta = random_plane(4, w * h, 2.0, 20.0);
    // flat patch: the ε under the root must keep the gradient finite there
    for v in beta.iter_mut().take(10) {
        *v = 2.0;
    }
    let mut g = vec![0.0; w * h];
    tv_isotropic(&beta, w, h, 1.3, &mut g).unwrap();
    assert!(
        g.iter().all(|v| v.is_finite()),
        "TV gradient not finite on a flat patch"
    );
    assert_fd(
        "L_smooth",
        &beta,
        &g,
        |x| 1.3 * tv_isotropic(x, w, h, 1.0, &mut vec![0.0; w * h]).unwrap(),
        1e-7,
        1e-5,
    );
}

/// Two views of a tilted plane at depth ~3 m with synthetic depth/alpha maps.
fn two_views() -> (
    GBuffers<f64>,
    s3tir_trainer::camera::PinholeCamera,
    GBuffers<f64>,
    s3tir_trainer::camera::PinholeCamera,
) {
    let (w, h) = (20, 16);
    let cam_i = s3tir_trainer::camera::PinholeCamera::look_at(
        [0.0; 3],
        [0.0, 0.0, 3.0],
        [0.0, -1.0, 0.0],
        18.0,
        w,
        h,
    );
    let cam_j = s3tir_trainer::camera::PinholeCamera::look_at(
        [0.4, 0.1, 0.0],
        [0.0, 0.0, 3.0],
        [0.0, -1.0, 0.0],
        18.0,
        w,
        h,
    );
    // Plane z = 3 + 0.1 x (world). Depth of pixel ray: solve along the ray.
    let view = |cam: &s3tir_trainer::camera::PinholeCamera, seed: u64| {
        let mut g = GBuffers::<f64>::zeros(w, h, false);
        let mut r = rng(seed);
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let o = cam.unproject(x as f64, y as f64, 0.0);
                let e = cam.unproject(x as f64, y as f64, 1.0);
                let d = [e[0] - o[0], e[1] - o[1], e[2] - o[2]];
                // o + t d on z − 0.1 x = 3
                let t = (3.0 - o[2] + 0.1 * o[0]) / (d[2] - 0.1 * d[0]);
                let alpha = 0.9;
                g.alpha[p] = alpha;
                g.depth[p] = alpha * t;
                g.psi_high[p] = r.random_range(0.0..1.0);
                g.psi_beta[p] = r.random_range(2.0..10.0);
            }
        }
        g
    };
    let vi = view(&cam_i, 7);
    let vj = view(&cam_j, 8);
    (vi, cam_i, vj, cam_j)
}

#[test]
fn consistency_gradient_matches_finite_differences_with_fixed_depth() {
    let (vi, ci, vj, cj) = two_views();
    let opt = ConsistencyOptions::default();
    let mut gi = GBuffers::zeros(vi.width, vi.height, false);
    let mut gj = GBuffers::zeros(vj.width, vj.height, false);
    let c = consistency_loss(&vi, &ci, &vj, &cj, &opt, 1.0, &mut gi, &mut gj).unwrap();
    let n = vi.width * vi.height;
    assert!(
        c.valid_px > n / 2,
        "most pixels see the shared plane: {} of {n} valid",
        c.valid_px
    );
    assert!(
        c.valid_px < n,
        "some pixels leave view j's image: {} of {n} valid",
        c.valid_px
    );
    let eval = |vi: &GBuffers<f64>, vj: &GBuffers<f64>| {
        let mut a = GBuffers::zeros(vi.width, vi.height, false);
        let mut b = GBuffers::zeros(vj.width, vj.height, false);
        consistency_loss(vi, &ci, vj, &cj, &opt, 1.0, &mut a, &mut b)
            .unwrap()
            .loss
    };
    assert_fd(
        "L_consist wrt Ψhigh_i",
        &vi.psi_high,
        &gi.psi_high,
        |x| {
            eval(
                &GBuffers {
                    psi_high: x.to_vec(),
                    ..vi.clone()
                },
                &vj,
            )
        },
        1e-8,
        1e-6,
    );
    assert_fd(
        "L_consist wrt Ψβ_i",
        &vi.psi_beta,
        &gi.psi_beta,
        |x| {
            eval(
                &GBuffers {
                    psi_beta: x.to_vec(),
                    ..vi.clone()
                },
                &vj,
            )
        },
        1e-8,
        1e-6,
    );
    assert_fd(
        "L_consist wrt Ψhigh_j",
        &vj.psi_high,
        &gj.psi_high,
        |x| {
            eval(
                &vi,
                &GBuffers {
                    psi_high: x.to_vec(),
                    ..vj.clone()
                },
            )
        },
        1e-8,
        1e-6,
    );
    assert_fd(
        "L_consist wrt Ψβ_j",
        &vj.psi_beta,
        &gj.psi_beta,
        |x| {
            eval(
                &vi,
                &GBuffers {
                    psi_beta: x.to_vec(),
                    ..vj.clone()
                },
            )
        },
        1e-8,
        1e-6,
    );
}

#[test]
fn consistency_is_zero_for_consistent_maps_and_masks_occlusion() {
    let (mut vi, ci, mut vj, cj) = two_views();
    // Frequency maps that are a function of the 3-D point: consistent by construction.
    let field = |p: [f64; 3]| (p[0] * 1.7 + p[1] * 0.3).sin() + 1.5;
    for (v, c) in [(&mut vi, &ci), (&mut vj, &cj)] {
        for y in 0..v.height {
            for x in 0..v.width {
                let p = y * v.width + x;
                let world = c.unproject(x as f64, y as f64, v.depth[p] / v.alpha[p]);
                v.psi_high[p] = field(world);
                v.psi_beta[p] = 2.0 + field(world);
            }
        }
    }
    let opt = ConsistencyOptions::default();
    let mut gi = GBuffers::zeros(vi.width, vi.height, false);
    let mut gj = GBuffers::zeros(vj.width, vj.height, false);
    let c = consistency_loss(&vi, &ci, &vj, &cj, &opt, 1.0, &mut gi, &mut gj).unwrap();
    // bilinear interpolation of a smooth field: small but not exactly zero
    assert!(
        c.loss < 0.02,
        "consistent maps give a near-zero loss, got {}",
        c.loss
    );
    // An occluder in view j (depth halved everywhere): every pixel must be masked.
    let mut occluded = vj.clone();
    for d in occluded.depth.iter_mut() {
        *d *= 0.5;
    }
    let c2 = consistency_loss(&vi, &ci, &occluded, &cj, &opt, 1.0, &mut gi, &mut gj).unwrap();
    assert_eq!(
        c2.valid_px, 0,
        "pixels occluded in view j must be masked, {} kept",
        c2.valid_px
    );
}

#[test]
fn view_loss_through_renderer_matches_finite_differences() {
    // End to end: eq. 6 without L_consist, pushed through the renderer.
    let mut r = rng(21);
    let mut prims = Primitives::<f64>::new(2, None);
    for beta in [2.0, 3.0, 9.0] {
        prims.push(&random_primitive(&mut r, [0.0, 0.0, 3.0], beta, 2, 0));
    }
    let cam = front_camera(20, 18, 20.0);
    let settings = RenderSettings::default();
    let target = random_plane(22, 20 * 18, 0.0, 1.0);
    let weights = LossWeights {
        lambda_sparse: 0.3,
        lambda_smooth: 0.2,
        ..LossWeights::default()
    };
    let loss = |p: &Primitives<f64>| {
        let out = render(p, &cam, &settings).unwrap();
        let mut up = GBuffers::zeros(out.width, out.height, false);
        view_loss(&out, &target, &weights, &mut up).unwrap().total
    };
    let out = render(&prims, &cam, &settings).unwrap();
    let mut up = GBuffers::zeros(out.width, out.height, false);
    view_loss(&out, &target, &weights, &mut up).unwrap();
    let g = render_backward(&prims, &cam, &settings, &up).unwrap();
    for (gi, (name, values)) in prims.groups().iter().enumerate() {
        let analytic = g.groups()[gi].1.clone();
        let values = (*values).clone();
        if values.is_empty() {
            continue; // no SH colour in this scene
        }
        assert_fd(
            &format!("eq. 6 through the renderer wrt {name}"),
            &values,
            &analytic,
            |x| {
                let mut p = prims.clone();
                *p.groups_mut()[gi].1 = x.to_vec();
                loss(&p)
            },
            1e-7,
            1e-4,
        );
    }
}

/// The per-view response (`loss::response`): the loss of the responded thermal plane w.r.t.
/// the rendered plane, the gain and the offset, against central differences; cases: a typical
/// AGC gain, a gain far below 1 (stiff: the rendered-plane gradient shrinks with it), and the
/// identity, which must reproduce `view_loss` exactly. The L1 kink (render equal to target
/// through the response: zero subgradient) is the stiff case of the offset: there the analytic
/// gradient must be exactly the SSIM part, checked against a target shifted off the kink.
#[test]
fn response_gradients_match_finite_differences() {
    use s3tir_trainer::loss::response::{ViewResponse, view_loss_with_response};
    let (w, h) = (15, 11);
    let n = w * h;
    let weights = LossWeights::default();
    let mut base = GBuffers::<f64>::zeros(w, h, false);
    base.thermal = random_plane(11, n, 0.1, 0.9);
    base.psi_high = random_plane(12, n, -0.2, 0.3);
    base.psi_beta = random_plane(13, n, 2.0, 4.0);
    let target = random_plane(14, n, 0.0, 1.0);
    for (label, gain, offset) in [
        ("agc", 0.8, 0.05),
        ("low gain", 0.05, -0.1),
        ("identity", 1.0, 0.0),
    ] {
        let resp = ViewResponse {
            gain,
            offset,
            pivot: 0.45,
        };
        let mut up = GBuffers::<f64>::zeros(w, h, false);
        let (l, g) = view_loss_with_response(&base, &target, &weights, &resp, &mut up).unwrap();
        let loss_of = |thermal: &[f64], r: &ViewResponse| {
            let mut gb = base.clone();
            gb.thermal = thermal.to_vec();
            let mut scratch = GBuffers::<f64>::zeros(w, h, false);
            view_loss_with_response(&gb, &target, &weights, r, &mut scratch)
                .unwrap()
                .0
                .total
        };
        assert_fd(
            &format!("{label}: dL/d(rendered thermal)"),
            &base.thermal,
            &up.thermal,
            |x| loss_of(x, &resp),
            1e-8,
            1e-5,
        );
        assert_fd(
            &format!("{label}: dL/d(gain, offset)"),
            &[gain, offset],
            &[g.gain, g.offset],
            |p| {
                loss_of(
                    &base.thermal,
                    &ViewResponse {
                        gain: p[0],
                        offset: p[1],
                        pivot: 0.45,
                    },
                )
            },
            1e-8,
            1e-5,
        );
        // The planes the response does not see get the plain terms' gradients.
        let mut plain_up = GBuffers::<f64>::zeros(w, h, false);
        let mut seen = base.clone();
        seen.thermal = base.thermal.iter().map(|&x| resp.apply(x)).collect();
        let plain = view_loss(&seen, &target, &weights, &mut plain_up).unwrap();
        assert!(
            (plain.total - l.total).abs() < 1e-12,
            "{label}: loss {} vs view_loss of the responded plane {}",
            l.total,
            plain.total
        );
        assert_eq!(
            plain_up.psi_beta, up.psi_beta,
            "{label}: Ψ_β gradient changed"
        );
        assert_eq!(
            plain_up.psi_high, up.psi_high,
            "{label}: Ψ_high gradient changed"
        );
    }
    // On the L1 kink (target = the responded render): the L1 part contributes nothing, so
    // dL/doffset is the SSIM part alone, which is 0 for identical images (SSIM at its maximum).
    let resp = ViewResponse {
        gain: 0.7,
        offset: 0.02,
        pivot: 0.5,
    };
    let on_kink: Vec<f64> = base.thermal.iter().map(|&x| resp.apply(x)).collect();
    let mut up = GBuffers::<f64>::zeros(w, h, false);
    let (l, g) = view_loss_with_response(&base, &on_kink, &weights, &resp, &mut up).unwrap();
    assert!(
        l.l1 == 0.0 && (l.ssim - 1.0).abs() < 1e-12,
        "kink: L1 {} SSIM {}",
        l.l1,
        l.ssim
    );
    assert!(
        g.offset.abs() < 1e-9 && g.gain.abs() < 1e-9,
        "at the optimum the response's gradient must vanish, got ({}, {})",
        g.gain,
        g.offset
    );
}
