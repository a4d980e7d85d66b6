//! `L_render = (1 − λ)·L1 + λ·(1 − SSIM)` on one image plane, with its gradient.
//!
//! SSIM as in 3DGS: 11×11 Gaussian window (σ = 1.5, normalised), zero padding ("same" size),
//! `C1 = 0.01²`, `C2 = 0.03²` (data range 1: inputs normalised to [0, 1]), averaged over all
//! pixels. L1 is the mean absolute difference; its subgradient at 0 is 0.
//!
//! For dark RGB, [`l1_low_dssim`] replaces L1 by TGA-GS's L1-low (paper §3.4),
//! `‖Φ(Ĉ + ε) − Φ(C + ε)‖₁` with ε = 10⁻³. The paper calls Φ "the inverse tone mapping curve"
//! and does not define it further; we take Φ = ln, the tone curve of RawNeRF's loss (which
//! Aleth-NeRF's Lit-MSE, the paper's inspiration, follows): it weighs a residual by the
//! inverse brightness, so the dark pixels that make up a low-light image count as much as
//! the few bright ones instead of vanishing under L1. Our rendered colours are ≥ 0 (SH colour
//! clamped at 0, blended with non-negative weights); a rendered value below 0 would be
//! clamped to 0 inside Φ with no gradient.
//!
//! Unlike the paper we multiply L1-low by the target's mean value plus ε, so that its pixel
//! weights `(mean + ε)/(Ĉ + ε)` average about 1 and its gradient has L1's size on a typical
//! pixel whatever the exposure: thermal and RGB views share the primitives' Adam moments,
//! and an unscaled log loss on a 2 %-exposure image (mean 0.07) pulled ~15× harder than the
//! thermal views' L1, so the RGB views alone set every step size and the thermal head
//! stopped training (measured: 18 dB held-out thermal against 30 dB thermal-only).

use super::check_len;
use crate::error::RenderError;
use crate::real::Real;
use rayon::prelude::*;

/// Window radius (11×11 window).
pub const SSIM_RADIUS: usize = 5;
/// Window standard deviation, pixels.
pub const SSIM_SIGMA_PX: f64 = 1.5;
const C1: f64 = 0.01 * 0.01;
const C2: f64 = 0.03 * 0.03;

/// Values of the photometric terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Photometric {
    pub l1: f64,
    pub ssim: f64,
    /// `(1 − λ)·l1 + λ·(1 − ssim)`.
    pub loss: f64,
}

fn window() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut g = [0.0; 2 * SSIM_RADIUS + 1];
    for (k, v) in g.iter_mut().enumerate() {
        let x = k as f64 - SSIM_RADIUS as f64;
        *v = (-x * x / (2.0 * SSIM_SIGMA_PX * SSIM_SIGMA_PX)).exp();
    }
    let s: f64 = g.iter().sum();
    g.map(|v| v / s)
}

/// Separable Gaussian blur with zero padding (self-adjoint: the kernel is symmetric). Rows are
/// blurred in parallel, each output pixel summed in the same order as alone: the same bit for
/// bit on any number of threads.
fn blur<T: Real>(src: &[T], w: usize, h: usize, g: &[T]) -> Vec<T> {
    let r = SSIM_RADIUS as isize;
    let mut tmp = vec![T::ZERO; w * h];
    let mut out = vec![T::ZERO; w * h];
    if w == 0 || h == 0 {
        return out;
    }
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, t) in row.iter_mut().enumerate() {
            let mut acc = T::ZERO;
            for (k, gk) in g.iter().enumerate() {
                let xx = x as isize + k as isize - r;
                if xx >= 0 && (xx as usize) < w {
                    acc += *gk * src[y * w + xx as usize];
                }
            }
            *t = acc;
        }
    });
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut acc = T::ZERO;
            for (k, gk) in g.iter().enumerate() {
                let yy = y as isize + k as isize - r;
                if yy >= 0 && (yy as usize) < h {
                    acc += *gk * tmp[yy as usize * w + x];
                }
            }
            *o = acc;
        }
    });
    out
}

/// Mean SSIM of `x` against `y` and, if `grad` is given, `d(mean SSIM)/dx` added with `scale`.
pub fn ssim<T: Real>(x: &[T], y: &[T], w: usize, h: usize, grad: Option<(&mut [T], T)>) -> f64 {
    let g: Vec<T> = window().iter().map(|v| T::from_f64(*v)).collect();
    let n = w * h;
    let xx: Vec<T> = x.iter().map(|v| *v * *v).collect();
    let yy: Vec<T> = y.iter().map(|v| *v * *v).collect();
    let xy: Vec<T> = x.iter().zip(y).map(|(a, b)| *a * *b).collect();
    let mu_x = blur(x, w, h, &g);
    let mu_y = blur(y, w, h, &g);
    let e_xx = blur(&xx, w, h, &g);
    let e_yy = blur(&yy, w, h, &g);
    let e_xy = blur(&xy, w, h, &g);
    let (c1, c2) = (T::from_f64(C1), T::from_f64(C2));
    let two = T::TWO;
    let mut sum = 0.0;
    let mut g_mu = vec![T::ZERO; n];
    let mut g_exx = vec![T::ZERO; n];
    let mut g_exy = vec![T::ZERO; n];
    for p in 0..n {
        let (mx, my) = (mu_x[p], mu_y[p]);
        let a1 = two * mx * my + c1;
        let a2 = two * (e_xy[p] - mx * my) + c2;
        let b1 = mx * mx + my * my + c1;
        let b2 = (e_xx[p] - mx * mx) + (e_yy[p] - my * my) + c2;
        let s = a1 * a2 / (b1 * b2);
        sum += s.to_f64();
        g_mu[p] = s * (two * my / a1 - two * my / a2 - two * mx / b1 + two * mx / b2);
        g_exx[p] = -s / b2;
        g_exy[p] = s * two / a2;
    }
    let mean = sum / n as f64;
    if let Some((out, scale)) = grad {
        let k = scale / T::from_f64(n as f64);
        let b_mu = blur(&g_mu, w, h, &g);
        let b_exx = blur(&g_exx, w, h, &g);
        let b_exy = blur(&g_exy, w, h, &g);
        for p in 0..n {
            out[p] += k * (b_mu[p] + two * x[p] * b_exx[p] + y[p] * b_exy[p]);
        }
    }
    mean
}

/// `(1 − λ)·L1 + λ·(1 − SSIM)` of `image` against `target`; adds `scale · dL/dimage` to `grad`.
pub fn l1_dssim<T: Real>(
    image: &[T],
    target: &[T],
    w: usize,
    h: usize,
    lambda_dssim: f64,
    scale: T,
    grad: &mut [T],
) -> Result<Photometric, RenderError> {
    residual_dssim(
        image,
        target,
        w,
        h,
        lambda_dssim,
        scale,
        grad,
        1.0,
        |a, b| {
            let d = a - b;
            (d.abs(), d.sign0())
        },
    )
}

/// `(1 − λ)·L1-low + λ·(1 − SSIM)` of `image` against `target` (module docs):
/// `L1-low = (C̄ + ε)·mean |ln(max(Ĉ, 0) + ε) − ln(C + ε)|` with `C̄` the target's mean,
/// gradient `(C̄ + ε)·sign(·)/(Ĉ + ε)` where Ĉ > 0; adds `scale · dL/dimage` to `grad`. The
/// returned `l1` field holds the L1-low value.
#[allow(clippy::too_many_arguments)]
pub fn l1_low_dssim<T: Real>(
    image: &[T],
    target: &[T],
    w: usize,
    h: usize,
    lambda_dssim: f64,
    eps: f64,
    scale: T,
    grad: &mut [T],
) -> Result<Photometric, RenderError> {
    let n = (w * h).max(1) as f64;
    let mean = target.iter().map(|v| v.to_f64().max(0.0)).sum::<f64>() / n;
    let e = T::from_f64(eps);
    residual_dssim(
        image,
        target,
        w,
        h,
        lambda_dssim,
        scale,
        grad,
        mean + eps,
        |a, b| {
            let positive = a > T::ZERO;
            let a_c = if positive { a } else { T::ZERO };
            let d = (a_c + e).ln() - (b.max(T::ZERO) + e).ln();
            let slope = if positive {
                d.sign0() / (a_c + e)
            } else {
                T::ZERO
            };
            (d.abs(), slope)
        },
    )
}

/// `(1 − λ)·norm·mean ρ(Ĉ, C) + λ·(1 − SSIM)` for a per-pixel residual `ρ` given with its
/// derivative in Ĉ by `pixel(Ĉ, C) = (ρ, ∂ρ/∂Ĉ)`; adds `scale · dL/dimage` to `grad`.
#[allow(clippy::too_many_arguments)]
fn residual_dssim<T: Real>(
    image: &[T],
    target: &[T],
    w: usize,
    h: usize,
    lambda_dssim: f64,
    scale: T,
    grad: &mut [T],
    norm: f64,
    pixel: impl Fn(T, T) -> (T, T),
) -> Result<Photometric, RenderError> {
    check_len("image", image.len(), w, h)?;
    check_len("target", target.len(), w, h)?;
    check_len("grad", grad.len(), w, h)?;
    let n = (w * h) as f64;
    let lam = T::from_f64(lambda_dssim);
    let k1 = scale * (T::ONE - lam) * T::from_f64(norm / n);
    let mut l1 = 0.0;
    for ((g, a), b) in grad.iter_mut().zip(image).zip(target) {
        let (rho, slope) = pixel(*a, *b);
        l1 += rho.to_f64();
        *g += k1 * slope;
    }
    let l1 = norm * l1 / n;
    let s = ssim(image, target, w, h, Some((grad, -scale * lam)));
    Ok(Photometric {
        l1,
        ssim: s,
        loss: (1.0 - lambda_dssim) * l1 + lambda_dssim * (1.0 - s),
    })
}
