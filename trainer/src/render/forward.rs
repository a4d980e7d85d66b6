//! Forward pass: per-pixel sample evaluation (shared with the backward pass) and front-to-back
//! blending.

use super::prepare::{Prepared, PrimView, prepare};
use super::{ALPHA_MAX, ALPHA_MIN, GBuffers, RenderSettings, T_MIN};
use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::primitive::Primitives;
use crate::real::{Real, v3};
use rayon::prelude::*;

/// One primitive evaluated at one pixel's peak point.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sample<T> {
    pub alpha: T,
    /// Support `S` at the peak.
    pub s: T,
    /// `o·S > ALPHA_MAX` (α clamped, zero gradient through `o·S`).
    pub clamped: bool,
    /// Squared Mahalanobis distance `q*` at the peak.
    pub q: T,
    /// `m^β = q*^{β/2}`.
    pub mb: T,
    /// Peak ray parameter = camera depth.
    pub t: T,
    /// Whitened residual `a + t* b`.
    pub r: [T; 3],
    /// Whitened ray direction `b`.
    pub b: [T; 3],
    pub bb: T,
    /// World ray direction `d`.
    pub d: [T; 3],
    /// `x* − μ`.
    pub delta: [T; 3],
    /// `F` (after ReLU) and whether the ReLU passes.
    pub f: T,
    pub f_active: bool,
}

/// Evaluates primitive `i` on the ray of pixel `(u, v)`; `None` if it does not contribute.
/// Always inlined: it is the inner loop of the forward and backward passes, and when LLVM's
/// heuristics left it out of line (they did after unrelated changes elsewhere in the crate)
/// the CPU backend took 1.6x as long per step.
#[inline(always)]
pub(crate) fn sample<T: Real>(
    prims: &Primitives<T>,
    prep: &Prepared<T>,
    pv: &PrimView<T>,
    i: usize,
    p: [T; 3],
) -> Option<Sample<T>> {
    let a = pv.a;
    let b = v3::mat_vec(&pv.b_mat, p);
    let bb = v3::dot(b, b);
    let t = -v3::dot(a, b) / bb;
    let in_front = t > T::from_f64(prep.settings.near_m); // false for NaN
    if !in_front {
        return None;
    }
    let r = v3::add(a, v3::scale(b, t));
    let q = v3::dot(r, r);
    // Cheap Gaussian path: at β = 2 exactly, q*^{β/2} = q* (same value, no pow).
    let mb = if pv.gaussian {
        q
    } else {
        q.powf(pv.beta * T::HALF)
    };
    let s = (-mb).exp();
    let os = pv.opacity * s;
    let clamped = os > T::from_f64(ALPHA_MAX);
    let alpha = if clamped { T::from_f64(ALPHA_MAX) } else { os };
    let visible = alpha >= T::from_f64(ALPHA_MIN); // false for NaN
    if !visible {
        return None;
    }
    let d = v3::mat_vec(&prep.pix_to_dir, p);
    let delta = v3::add(pv.c_minus_mu, v3::scale(d, t));
    let pre = if prep.thermal {
        spectrum_pre(prims, pv, i, delta).0
    } else {
        T::ZERO
    };
    let f_active = pre > T::ZERO;
    Some(Sample {
        alpha,
        s,
        clamped,
        q,
        mb,
        t,
        r,
        b,
        bb,
        d,
        delta,
        f: if f_active { pre } else { T::ZERO },
        f_active,
    })
}

/// Pre-ReLU spectrum `ω_low + Σ_j ω_j cos θ_j` over the live bands at offset `delta = x − μ`.
#[inline]
pub(crate) fn spectrum_pre<T: Real>(
    prims: &Primitives<T>,
    pv: &PrimView<T>,
    i: usize,
    delta: [T; 3],
) -> (T, ()) {
    let m = prims.bands;
    let two_pi = T::from_f64(std::f64::consts::TAU);
    let mut pre = prims.omega_low[i];
    for j in 0..pv.live_bands {
        let k = m * i + j;
        let fr = [
            prims.band_freq[3 * k],
            prims.band_freq[3 * k + 1],
            prims.band_freq[3 * k + 2],
        ];
        let theta = two_pi * v3::dot(fr, delta) + prims.band_phase[k];
        pre += prims.band_amp[k] * theta.cos();
    }
    (pre, ())
}

/// The values a sample contributes to the 9 blended outputs, in buffer order: thermal `F`,
/// Ψ_low, Ψ_high, Ψ_β, depth `t*`, alpha (1), RGB colour. Shared by forward and backward.
#[inline]
pub(crate) fn blended_values<T: Real>(
    prims: &Primitives<T>,
    pv: &PrimView<T>,
    i: usize,
    s: &Sample<T>,
) -> [T; 9] {
    [
        s.f,
        prims.omega_low[i],
        pv.psi_high,
        pv.beta,
        s.t,
        T::ONE,
        pv.colour[0],
        pv.colour[1],
        pv.colour[2],
    ]
}

/// Pixel centre `(x, y, 1)` in the scalar type.
#[inline]
pub(crate) fn pixel<T: Real>(x: usize, y: usize) -> [T; 3] {
    [T::from_f64(x as f64), T::from_f64(y as f64), T::ONE]
}

/// Renders the image and G-buffers of `prims` seen by `cam`.
pub fn render<T: Real>(
    prims: &Primitives<T>,
    cam: &PinholeCamera,
    settings: &RenderSettings,
) -> Result<GBuffers<T>, RenderError> {
    let prep = prepare(prims, cam, settings)?;
    Ok(render_prepared(prims, &prep))
}

/// The G-buffers of `prims` seen by `cam` without the thermal image (its plane is zero; see
/// [`Prepared::thermal`]).
pub fn render_gbuffers<T: Real>(
    prims: &Primitives<T>,
    cam: &PinholeCamera,
    settings: &RenderSettings,
) -> Result<GBuffers<T>, RenderError> {
    let mut prep = prepare(prims, cam, settings)?;
    prep.thermal = false;
    Ok(render_prepared(prims, &prep))
}

/// The samples pixel `p` blends, front to back over the primitives of its tile `list`:
/// `visit(position in list, primitive, transmittance before it, sample)` for each, up to the
/// early stop (module docs of `render`). Shared by the forward and the backward pass, which
/// must see the same samples.
#[inline]
pub(crate) fn front_to_back<T: Real>(
    prims: &Primitives<T>,
    prep: &Prepared<T>,
    list: &[u32],
    p: [T; 3],
    mut visit: impl FnMut(usize, usize, T, &Sample<T>),
) {
    let t_min = T::from_f64(T_MIN);
    let mut trans = T::ONE;
    for (k, &i) in list.iter().enumerate() {
        let i = i as usize;
        let Some(s) = sample(prims, prep, &prep.prims[i], i, p) else {
            continue;
        };
        let next = trans * (T::ONE - s.alpha);
        if next < t_min {
            break;
        }
        visit(k, i, trans, &s);
        trans = next;
    }
}

/// Forward pass on prepared per-view data. Rows are rendered in parallel; each pixel is
/// independent, so the result is the same bit for bit on any number of threads.
pub fn render_prepared<T: Real>(prims: &Primitives<T>, prep: &Prepared<T>) -> GBuffers<T> {
    let _span = tracing::trace_span!("cpu_render_forward", primitives = prep.order.len()).entered();
    let has_rgb = prims.sh_k() > 0;
    let mut out = GBuffers::zeros(prep.width, prep.height, has_rgb);
    let npix = prep.width * prep.height;
    if npix == 0 {
        return out;
    }
    let mut accs = vec![[T::ZERO; 9]; npix];
    accs.par_chunks_mut(prep.width)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, acc) in row.iter_mut().enumerate() {
                let list = &prep.tile_lists[prep.tile_of(x, y)];
                front_to_back(prims, prep, list, pixel::<T>(x, y), |_, i, trans, s| {
                    let w = trans * s.alpha;
                    let vals = blended_values(prims, &prep.prims[i], i, s);
                    for (a, v) in acc.iter_mut().zip(vals) {
                        *a += w * v;
                    }
                });
            }
        });
    for (pidx, acc) in accs.iter().enumerate() {
        out.thermal[pidx] = acc[0];
        out.psi_low[pidx] = acc[1];
        out.psi_high[pidx] = acc[2];
        out.psi_beta[pidx] = acc[3];
        out.depth[pidx] = acc[4];
        out.alpha[pidx] = acc[5];
        if has_rgb {
            for c in 0..3 {
                out.rgb[c * npix + pidx] = acc[6 + c];
            }
        }
    }
    out
}
