//! Physics-inspired priors on the G-buffers (paper eq. 7–8).
//!
//! - `L_sparse = (1/HW) Σ |Ψ_high|` (subgradient 0 at 0);
//! - `L_smooth = (1/HW) Σ √(Δx² + Δy² + ε)` on Ψ_β with forward differences (`Δ = 0` past the last
//!   column/row) and [`TV_EPSILON`] under the root so the gradient is finite on flat regions.

use super::check_len;
use crate::error::RenderError;
use crate::real::Real;

/// ε under the TV root (Ψ_β is in β units, ≥ 2 where covered).
pub const TV_EPSILON: f64 = 1e-6;

/// `mean |psi|`; adds `weight · d/dpsi` to `grad`.
pub fn l1_sparsity<T: Real>(psi: &[T], weight: T, grad: &mut [T]) -> f64 {
    let n = psi.len().max(1) as f64;
    let k = weight / T::from_f64(n);
    let mut sum = 0.0;
    for (g, v) in grad.iter_mut().zip(psi) {
        sum += v.abs().to_f64();
        *g += k * v.sign0();
    }
    sum / n
}

/// Isotropic TV (mean over pixels); adds `weight · d/dpsi` to `grad`.
pub fn tv_isotropic<T: Real>(
    psi: &[T],
    w: usize,
    h: usize,
    weight: T,
    grad: &mut [T],
) -> Result<f64, RenderError> {
    check_len("psi", psi.len(), w, h)?;
    check_len("grad", grad.len(), w, h)?;
    let n = (w * h) as f64;
    let k = weight / T::from_f64(n);
    let eps = T::from_f64(TV_EPSILON);
    let mut sum = 0.0;
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let dx = if x + 1 < w {
                psi[p + 1] - psi[p]
            } else {
                T::ZERO
            };
            let dy = if y + 1 < h {
                psi[p + w] - psi[p]
            } else {
                T::ZERO
            };
            let norm = (dx * dx + dy * dy + eps).sqrt();
            sum += norm.to_f64();
            let gx = k * dx / norm;
            let gy = k * dy / norm;
            if x + 1 < w {
                grad[p + 1] += gx;
                grad[p] -= gx;
            }
            if y + 1 < h {
                grad[p + w] += gy;
                grad[p] -= gy;
            }
        }
    }
    Ok(sum / n)
}
