//! Backward pass: exact gradients of every output buffer w.r.t. every parameter, through the
//! reverse blending recurrence.
//!
//! Each pixel's samples are recomputed front to back (no stored per-pixel lists, no division by
//! `1 − α`), then walked back to front with `S_after = Σ_{l>i} α_l w_l Π_{i<k<l}(1 − α_k)`:
//! `dL/dα_i = T_i (w_i − S_after)` where `w_i = Σ_k g_k v_{i,k}` is the upstream-weighted value.
//! Per sample the chain is `α → (o, S) → (q*, β)` and `(q*, t*) → (a, b) → (N, μ)`, with
//! `∂q*/∂a = 2r`, `∂q*/∂b = 2t* r` (envelope theorem: `t*` minimises `q`), `∂t*/∂a = −b/b·b`,
//! `∂t*/∂b = −(a + 2t* b)/b·b`. Special cases: `∂S/∂β = −S m^β ln m` is taken as 0 at `m = 0`;
//! the ReLU of `F` and of the colour pass gradient only where their input is > 0; the α clamp
//! blocks the gradient to `o` and `S`; β on its clamp blocks the gradient to `beta_raw`;
//! `sign(0) = 0` for `|ω_j|`. The early-stop threshold and the α ≥ 1/255 cut are treated as
//! constants (as in 3DGS): gradients are those of the blended sum over the samples taken.

use super::forward::{blended_values, front_to_back, pixel};
use super::prepare::{Prepared, prepare};
use super::{GBuffers, RenderSettings, TILE_SIZE};
use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::primitive::{Primitives, quat_backward};
use crate::real::{Real, v3};
use crate::sh;
use rayon::prelude::*;

#[derive(Debug, Clone, Copy, Default)]
struct Acc<T> {
    g_a: [T; 3],
    /// `Σ dL/db ⊗ (u, v, 1)`.
    g_bp: [T; 9],
    g_mu: [T; 3],
    g_o: T,
    g_beta: T,
    g_colour: [T; 3],
    touched: bool,
}

impl<T: Real> Acc<T> {
    fn add(&mut self, o: &Self) {
        for (a, b) in self.g_a.iter_mut().zip(o.g_a) {
            *a += b;
        }
        for (a, b) in self.g_bp.iter_mut().zip(o.g_bp) {
            *a += b;
        }
        for (a, b) in self.g_mu.iter_mut().zip(o.g_mu) {
            *a += b;
        }
        self.g_o += o.g_o;
        self.g_beta += o.g_beta;
        for (a, b) in self.g_colour.iter_mut().zip(o.g_colour) {
            *a += b;
        }
        self.touched |= o.touched;
    }
}

/// Gradient w.r.t. every parameter of `prims` (same layout as `prims`) given `dL/d(buffer)` for
/// every buffer in `upstream` (an empty buffer counts as zero).
pub fn render_backward<T: Real>(
    prims: &Primitives<T>,
    cam: &PinholeCamera,
    settings: &RenderSettings,
    upstream: &GBuffers<T>,
) -> Result<Primitives<T>, RenderError> {
    let mut prep = prepare(prims, cam, settings)?;
    check_upstream(&prep, upstream)?;
    // Without thermal upstream the spectrum's value does not enter any gradient: skip the band
    // phases (exactly the same gradients, the bands still get Ψ_high's).
    prep.thermal = upstream.thermal.iter().any(|g| *g != T::ZERO);
    Ok(render_backward_prepared(prims, &prep, upstream))
}

fn check_upstream<T: Real>(prep: &Prepared<T>, g: &GBuffers<T>) -> Result<(), RenderError> {
    let n = prep.width * prep.height;
    for (name, v) in g.planes() {
        let expected = if name == "rgb" { 3 * n } else { n };
        if !v.is_empty() && v.len() != expected {
            return Err(RenderError::BufferSize {
                buffer: name,
                width: prep.width,
                height: prep.height,
                expected,
                actual: v.len(),
            });
        }
    }
    Ok(())
}

/// Tiles whose partial sums are held at once (bounds the memory of the parallel backward pass:
/// one [`Acc`] and the band slots per primitive per tile of a batch).
const BACKWARD_BATCH_TILES: usize = 64;

/// One tile's gradient sums, indexed like the tile's primitive list: [`Acc`] and `ω_low`, then
/// per primitive the band slots' `[amp; m] [phase; m] [freq; 3m]`.
struct TileSums<T> {
    acc: Vec<Acc<T>>,
    omega_low: Vec<T>,
    bands: Vec<T>,
}

/// Backward pass on prepared per-view data (upstream sizes must match the view).
///
/// Tiles run in parallel, each summing its own pixels' contributions per primitive of its list;
/// the tiles' sums are then added in tile order. The partition into tiles and the order of
/// every addition are fixed, so the gradients are the same bit for bit on any number of
/// threads (`tests/cpu_threads.rs`).
pub fn render_backward_prepared<T: Real>(
    prims: &Primitives<T>,
    prep: &Prepared<T>,
    upstream: &GBuffers<T>,
) -> Primitives<T> {
    let _span =
        tracing::trace_span!("cpu_render_backward", primitives = prep.order.len()).entered();
    let mut grads = prims.zeros_like();
    let mut acc = vec![Acc::<T>::default(); prims.len()];
    let m = prims.bands;
    let tiles: Vec<usize> = (0..prep.tile_lists.len()).collect();
    for batch in tiles.chunks(BACKWARD_BATCH_TILES) {
        let sums: Vec<TileSums<T>> = batch
            .par_iter()
            .map(|&t| backward_tile(prims, prep, upstream, t))
            .collect();
        for (&t, sums) in batch.iter().zip(sums) {
            for (k, &i) in prep.tile_lists[t].iter().enumerate() {
                let local = &sums.acc[k];
                if !local.touched {
                    continue;
                }
                let i = i as usize;
                acc[i].add(local);
                grads.omega_low[i] += sums.omega_low[k];
                let live = prep.prims[i].live_bands;
                let at = 5 * m * k;
                for j in 0..live {
                    let g = m * i + j;
                    grads.band_amp[g] += sums.bands[at + j];
                    grads.band_phase[g] += sums.bands[at + m + j];
                    for a in 0..3 {
                        grads.band_freq[3 * g + a] += sums.bands[at + 2 * m + 3 * j + a];
                    }
                }
            }
        }
    }
    finish_backward(prims, prep, &acc, grads)
}

/// One tile's pixels, back to front per pixel (module docs), summed per primitive of the tile.
// Why this stays long: the CPU reference of `raster_backward.glsl`, pixel by pixel in the
// shader's order so the parity and finite-difference tests compare like with like; its
// accumulators (transmittance, running sums per plane) live across the whole walk.
fn backward_tile<T: Real>(
    prims: &Primitives<T>,
    prep: &Prepared<T>,
    upstream: &GBuffers<T>,
    tile: usize,
) -> TileSums<T> {
    let list = &prep.tile_lists[tile];
    let m = prims.bands;
    let mut out = TileSums {
        acc: vec![Acc::<T>::default(); list.len()],
        omega_low: vec![T::ZERO; list.len()],
        bands: vec![T::ZERO; 5 * m * list.len()],
    };
    if list.is_empty() {
        return out;
    }
    let npix = prep.width * prep.height;
    let two_pi = T::from_f64(std::f64::consts::TAU);
    let up = |v: &Vec<T>, idx: usize| v.get(idx).copied().unwrap_or(T::ZERO);
    let mut samples = Vec::new();
    let (tx, ty) = (tile % prep.tiles_x, tile / prep.tiles_x);
    let (x0, y0) = (tx * TILE_SIZE, ty * TILE_SIZE);
    for y in y0..(y0 + TILE_SIZE).min(prep.height) {
        for x in x0..(x0 + TILE_SIZE).min(prep.width) {
            let pidx = y * prep.width + x;
            let g = [
                up(&upstream.thermal, pidx),
                up(&upstream.psi_low, pidx),
                up(&upstream.psi_high, pidx),
                up(&upstream.psi_beta, pidx),
                up(&upstream.depth, pidx),
                up(&upstream.alpha, pidx),
                up(&upstream.rgb, pidx),
                up(&upstream.rgb, npix + pidx),
                up(&upstream.rgb, 2 * npix + pidx),
            ];
            if g.iter().all(|v| *v == T::ZERO) {
                continue;
            }
            let p = pixel::<T>(x, y);
            // Recompute the front-to-back samples with their transmittance.
            samples.clear();
            front_to_back(prims, prep, list, p, |k, i, trans, s| {
                samples.push((k, i, trans, *s))
            });
            let mut s_after = T::ZERO;
            for &(k, i, trans_i, s) in samples.iter().rev() {
                let pv = &prep.prims[i];
                let vals = blended_values(prims, pv, i, &s);
                let w_i = g.iter().zip(vals).fold(T::ZERO, |a, (gk, vk)| a + *gk * vk);
                let d_alpha = trans_i * (w_i - s_after);
                s_after = s.alpha * w_i + (T::ONE - s.alpha) * s_after;
                let wt = trans_i * s.alpha;
                let dv: [T; 9] = std::array::from_fn(|c| wt * g[c]);

                let ac = &mut out.acc[k];
                ac.touched = true;
                for c in 0..3 {
                    ac.g_colour[c] += dv[6 + c];
                }
                // Spectrum.
                let g_f = if s.f_active { dv[0] } else { T::ZERO };
                out.omega_low[k] += dv[1] + g_f;
                let mut g_delta = [T::ZERO; 3];
                let at = 5 * m * k;
                // Dropped slots (j ≥ live) are not part of the model: zero gradient.
                for j in 0..pv.live_bands {
                    let kb = m * i + j;
                    let amp = prims.band_amp[kb];
                    out.bands[at + j] += dv[2] * amp.sign0();
                    if g_f != T::ZERO {
                        let fr = [
                            prims.band_freq[3 * kb],
                            prims.band_freq[3 * kb + 1],
                            prims.band_freq[3 * kb + 2],
                        ];
                        let theta = two_pi * v3::dot(fr, s.delta) + prims.band_phase[kb];
                        out.bands[at + j] += g_f * theta.cos();
                        let g_theta = -g_f * amp * theta.sin();
                        out.bands[at + m + j] += g_theta;
                        for a in 0..3 {
                            out.bands[at + 2 * m + 3 * j + a] += g_theta * two_pi * s.delta[a];
                            g_delta[a] += g_theta * two_pi * fr[a];
                        }
                    }
                }
                // δ = (c − μ) + t* d.
                for (gm, gd) in ac.g_mu.iter_mut().zip(g_delta) {
                    *gm -= gd;
                }
                let g_t = v3::dot(g_delta, s.d) + dv[4];
                // Support and opacity.
                ac.g_beta += dv[3];
                let mut g_q = T::ZERO;
                if !s.clamped {
                    ac.g_o += d_alpha * s.s;
                    let g_s = d_alpha * pv.opacity;
                    // Cheap Gaussian path: at β = 2 exactly, (β/2) q*^{β/2 − 1} = 1.
                    g_q = if pv.gaussian {
                        -g_s * s.s
                    } else {
                        let half_beta = pv.beta * T::HALF;
                        -g_s * s.s * half_beta * s.q.powf(half_beta - T::ONE)
                    };
                    // ∂S/∂β only matters through dβ/dbeta_raw, exactly 0 for a frozen β.
                    if s.q > T::ZERO && pv.d_beta != T::ZERO {
                        ac.g_beta += -g_s * s.s * s.mb * T::HALF * s.q.ln();
                    }
                }
                // (q*, t*) → (a, b).
                let inv_bb = T::ONE / s.bb;
                let two = T::TWO;
                for c in 0..3 {
                    ac.g_a[c] += g_q * two * s.r[c] - g_t * s.b[c] * inv_bb;
                    let g_b =
                        g_q * two * s.t * s.r[c] - g_t * (pv.a[c] + two * s.t * s.b[c]) * inv_bb;
                    for (col, pc) in p.iter().enumerate() {
                        ac.g_bp[3 * c + col] += g_b * *pc;
                    }
                }
            }
        }
    }
    out
}

/// The per-primitive sums → gradients of the parameters (through `N`, the SH colour, the
/// opacity and β parameterisations).
fn finish_backward<T: Real>(
    prims: &Primitives<T>,
    prep: &Prepared<T>,
    acc: &[Acc<T>],
    mut grads: Primitives<T>,
) -> Primitives<T> {
    let k_sh = prims.sh_k();
    let w = &prep.pix_to_dir;
    for (i, ac) in acc.iter().enumerate() {
        if !ac.touched {
            continue;
        }
        let pv = &prep.prims[i];
        // dL/dN = g_a ⊗ (c − μ) + g_bp Wᵀ.
        let mut g_n = [T::ZERO; 9];
        for r in 0..3 {
            for c in 0..3 {
                let bw = ac.g_bp[3 * r] * w[3 * c]
                    + ac.g_bp[3 * r + 1] * w[3 * c + 1]
                    + ac.g_bp[3 * r + 2] * w[3 * c + 2];
                g_n[3 * r + c] = ac.g_a[r] * pv.c_minus_mu[c] + bw;
            }
        }
        let nt_ga = v3::mat_t_vec(&pv.n_mat, ac.g_a);
        let mut g_mu = v3::sub(ac.g_mu, nt_ga);
        if k_sh > 0 {
            let coeffs = &prims.sh[3 * k_sh * i..3 * k_sh * (i + 1)];
            let g_coeffs = &mut grads.sh[3 * k_sh * i..3 * k_sh * (i + 1)];
            let g_v = sh::backward(coeffs, k_sh, pv.sh_dir, pv.sh_norm, ac.g_colour, g_coeffs);
            g_mu = v3::add(g_mu, g_v);
        }
        for (g, v) in grads.means[3 * i..3 * i + 3].iter_mut().zip(g_mu) {
            *g += v;
        }
        // N_rc = R_cr / s_r.
        let mut g_rot = [T::ZERO; 9];
        for r in 0..3 {
            let mut g_ls = T::ZERO;
            for c in 0..3 {
                g_ls -= g_n[3 * r + c] * pv.n_mat[3 * r + c];
                g_rot[3 * c + r] = g_n[3 * r + c] / pv.scales[r];
            }
            grads.log_scales[3 * i + r] += g_ls;
        }
        let gq = quat_backward(pv.unit_quat, pv.quat_norm, &g_rot);
        for (g, v) in grads.quats[4 * i..4 * i + 4].iter_mut().zip(gq) {
            *g += v;
        }
        grads.opacity_logits[i] += ac.g_o * pv.d_opacity;
        grads.beta_raw[i] += ac.g_beta * pv.d_beta;
    }
    grads
}
