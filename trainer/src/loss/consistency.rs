//! Multi-view frequency consistency (paper eq. 4–5).
//!
//! For each pixel `u` of the reference view i with expected depth `D_i(u) = depth/alpha`
//! (only where `alpha ≥ min_alpha`), the surface point `X = world_from_cam_i · D_i(u) K_i⁻¹ u` is
//! projected into the source view j. The pixel is **masked out** when `X` is behind j's near
//! plane, projects outside j's image (bilinear footprint must lie inside), any of the four source
//! pixels has `alpha < min_alpha`, or it is **occluded** in j: `z_j(X) > D_j(u_j)·(1 + depth_rel_tol)`
//! with `D_j(u_j)` the bilinear expected depth of view j. Then
//! `L = (1/HW_i) Σ_valid |Ψhigh_i(u) − Ψhigh_j(u_j)| + |Ψβ_i(u) − Ψβ_j(u_j)|`, `Ψ_j(u_j)` bilinear.
//!
//! Differences from the paper (the wording wins where they differ): eq. 5 is a plain L1
//! sum; here it is averaged over the reference view's `HW` pixels like eq. 7–8, so λc = 0.01
//! does not depend on the resolution. Eq. 4 warps by the rendered depth `D_i`; here that is the
//! expected depth `depth/alpha`, with low-alpha pixels masked (the blended `depth` alone is
//! biased towards 0 where coverage is partial).
//!
//! **Gradients**: to `Ψ_high` and `Ψ_β` of both views (through the bilinear weights' values).
//! The warp coordinates and the mask are under **stop-gradient**: no gradient reaches the depth
//! maps, the alpha maps or the cameras through this term (the geometry is driven by the
//! photometric loss; the consistency term anchors the frequency maps to it).
//!
//! Rows of the reference view run on rayon's pool; their sums and scatters into view j are added
//! in row order, so the loss and gradients have the same bits on any thread count
//! (`tests/cpu_threads.rs`).

use rayon::prelude::*;

use super::check_len;
use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::real::Real;
use crate::render::GBuffers;

/// Warp and mask options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConsistencyOptions {
    /// Pixels with accumulated alpha below this have no depth and are masked.
    pub min_alpha: f64,
    /// Relative depth tolerance of the occlusion test.
    pub depth_rel_tol: f64,
    /// Near plane of the source view, metres.
    pub near_m: f64,
}

impl Default for ConsistencyOptions {
    fn default() -> Self {
        Self {
            min_alpha: 0.5,
            depth_rel_tol: 0.05,
            near_m: 0.01,
        }
    }
}

/// Value and number of valid (unmasked) pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Consistency {
    pub loss: f64,
    pub valid_px: usize,
}

/// One source pixel's bilinear footprint: four indices and weights.
type Footprint = [(usize, f64); 4];

/// One row of the reference view: its loss sum and, per valid pixel, the footprint in view j
/// and the upstream `[dL/dΨhigh, dL/dΨβ]` to scatter there.
struct RowScatter<T> {
    sum: f64,
    scatter: Vec<(Footprint, [T; 2])>,
}

/// Where pixel `(x, y)` of view i lands in view j (None: masked). Computed in f64 (stop-gradient).
fn warp_pixel<T: Real>(
    x: usize,
    y: usize,
    view_i: &GBuffers<T>,
    cam_i: &PinholeCamera,
    view_j: &GBuffers<T>,
    cam_j: &PinholeCamera,
    opt: &ConsistencyOptions,
) -> Option<Footprint> {
    let p = y * view_i.width + x;
    let d_i = view_i
        .expected_depth(p, T::from_f64(opt.min_alpha))?
        .to_f64();
    let world = cam_i.unproject(x as f64, y as f64, d_i);
    let pc = cam_j.to_cam(world);
    let in_front = pc[2] > opt.near_m; // false for NaN
    if !in_front {
        return None;
    }
    let [u, v] = cam_j.project_cam(pc);
    let (wj, hj) = (view_j.width, view_j.height);
    if !(u >= 0.0 && v >= 0.0 && u <= (wj - 1) as f64 && v <= (hj - 1) as f64) {
        return None;
    }
    let (x0, y0) = (u.floor() as usize, v.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(wj - 1), (y0 + 1).min(hj - 1));
    let (fx, fy) = (u - x0 as f64, v - y0 as f64);
    let fp = [
        (y0 * wj + x0, (1.0 - fx) * (1.0 - fy)),
        (y0 * wj + x1, fx * (1.0 - fy)),
        (y1 * wj + x0, (1.0 - fx) * fy),
        (y1 * wj + x1, fx * fy),
    ];
    let min_a = T::from_f64(opt.min_alpha);
    let mut d_j = 0.0;
    for &(q, wgt) in &fp {
        d_j += wgt * view_j.expected_depth(q, min_a)?.to_f64();
    }
    if pc[2] > d_j * (1.0 + opt.depth_rel_tol) {
        return None;
    }
    Some(fp)
}

/// `L_consist` of reference view i against source view j. Adds `weight · dL/dΨ` to the
/// `psi_high`/`psi_beta` planes of `grad_i` and `grad_j`.
#[allow(clippy::too_many_arguments)]
pub fn consistency_loss<T: Real>(
    view_i: &GBuffers<T>,
    cam_i: &PinholeCamera,
    view_j: &GBuffers<T>,
    cam_j: &PinholeCamera,
    opt: &ConsistencyOptions,
    weight: T,
    grad_i: &mut GBuffers<T>,
    grad_j: &mut GBuffers<T>,
) -> Result<Consistency, RenderError> {
    let (wi, hi) = (view_i.width, view_i.height);
    let (wj, hj) = (view_j.width, view_j.height);
    if cam_i.width != wi || cam_i.height != hi || cam_j.width != wj || cam_j.height != hj {
        return Err(RenderError::InvalidCamera {
            camera: "consistency",
            reason: "camera size differs from its buffers",
        });
    }
    for (name, len, w, h) in [
        ("view_i.psi_high", view_i.psi_high.len(), wi, hi),
        ("view_i.psi_beta", view_i.psi_beta.len(), wi, hi),
        ("view_i.depth", view_i.depth.len(), wi, hi),
        ("view_i.alpha", view_i.alpha.len(), wi, hi),
        ("view_j.psi_high", view_j.psi_high.len(), wj, hj),
        ("view_j.psi_beta", view_j.psi_beta.len(), wj, hj),
        ("view_j.depth", view_j.depth.len(), wj, hj),
        ("view_j.alpha", view_j.alpha.len(), wj, hj),
        ("grad_i.psi_high", grad_i.psi_high.len(), wi, hi),
        ("grad_i.psi_beta", grad_i.psi_beta.len(), wi, hi),
        ("grad_j.psi_high", grad_j.psi_high.len(), wj, hj),
        ("grad_j.psi_beta", grad_j.psi_beta.len(), wj, hj),
    ] {
        check_len(name, len, w, h)?;
    }
    let n = (wi * hi) as f64;
    let k = weight / T::from_f64(n);
    // Rows of view i in parallel: each row warps its pixels, writes its own row of `grad_i`
    // and returns its scatter into view j (footprint and the two upstream values per pixel);
    // the scatters and the row sums are then added in row order, so the result has the same
    // bits on any number of threads.
    let rows: Vec<RowScatter<T>> = grad_i
        .psi_high
        .par_chunks_mut(wi)
        .zip(grad_i.psi_beta.par_chunks_mut(wi))
        .enumerate()
        .map(|(y, (gi_high, gi_beta))| {
            let mut row = RowScatter {
                sum: 0.0,
                scatter: Vec::new(),
            };
            for (x, (gh, gb)) in gi_high.iter_mut().zip(gi_beta.iter_mut()).enumerate() {
                let Some(fp) = warp_pixel(x, y, view_i, cam_i, view_j, cam_j, opt) else {
                    continue;
                };
                let p = y * wi + x;
                let mut g = [T::ZERO; 2];
                for (which, (src_i, src_j)) in [
                    (&view_i.psi_high, &view_j.psi_high),
                    (&view_i.psi_beta, &view_j.psi_beta),
                ]
                .into_iter()
                .enumerate()
                {
                    let warped = fp
                        .iter()
                        .fold(T::ZERO, |acc, &(q, wgt)| acc + T::from_f64(wgt) * src_j[q]);
                    let diff = src_i[p] - warped;
                    row.sum += diff.abs().to_f64();
                    g[which] = k * diff.sign0();
                }
                *gh += g[0];
                *gb += g[1];
                row.scatter.push((fp, g));
            }
            row
        })
        .collect();
    let mut sum = 0.0;
    let mut valid_px = 0;
    for row in rows {
        sum += row.sum;
        valid_px += row.scatter.len();
        for (fp, [g_high, g_beta]) in row.scatter {
            for &(q, wgt) in &fp {
                grad_j.psi_high[q] -= g_high * T::from_f64(wgt);
                grad_j.psi_beta[q] -= g_beta * T::from_f64(wgt);
            }
        }
    }
    Ok(Consistency {
        loss: sum / n,
        valid_px,
    })
}
