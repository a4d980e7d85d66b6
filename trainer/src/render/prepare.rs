//! Per-view setup: per-primitive whitening matrices, opacity/β, colour, the culling box, the depth
//! order and the per-tile lists (see the parent module for the maths and the culling proof).

use super::{ALPHA_MIN, CULL_PAD_PX, RenderSettings, TILE_SIZE};
use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::primitive::{Primitives, rotation_from_quat};
use crate::real::{Real, v3};
use crate::sh;
use rayon::prelude::*;

/// One primitive as seen from one view.
#[derive(Debug, Clone, Copy, Default)]
pub struct PrimView<T> {
    /// In front of the near plane, opacity ≥ 1/255, finite whitening.
    pub visible: bool,
    /// Sort key: camera-frame z of μ (metres).
    pub depth_z_m: f64,
    /// Culling box in pixels `[u_min, v_min, u_max, v_max]` (padded); the whole image when the
    /// culling ellipsoid reaches the near plane.
    pub bbox_px: [f64; 4],
    /// Tiles `[tx0, ty0, tx1, ty1)` the primitive is listed in.
    pub tile_rect: [usize; 4],
    /// `N = diag(1/s) Rᵀ` (row-major).
    pub n_mat: [T; 9],
    /// `a = N (c − μ)`.
    pub a: [T; 3],
    /// `B = N W`: the whitened ray direction of pixel `(u, v)` is `B (u, v, 1)`.
    pub b_mat: [T; 9],
    /// `c − μ` (world).
    pub c_minus_mu: [T; 3],
    pub rot: [T; 9],
    pub unit_quat: [T; 4],
    pub quat_norm: T,
    pub scales: [T; 3],
    pub opacity: T,
    pub d_opacity: T,
    pub beta: T,
    pub d_beta: T,
    /// β is exactly 2: the support is evaluated as `exp(−q*)` without `pow` (the cheap Gaussian
    /// path; an exact shortcut of `q*^{β/2}` at β = 2, see the parent module).
    pub gaussian: bool,
    /// Live bands (`Primitives::live_bands`): the spectrum loops over these slots only.
    pub live_bands: usize,
    /// `Σ_j |ω_j|` over the live bands.
    pub psi_high: T,
    pub colour: [T; 3],
    pub sh_dir: [T; 3],
    pub sh_norm: T,
}

/// Everything the forward and backward passes need for one view.
#[derive(Debug, Clone)]
pub struct Prepared<T> {
    pub settings: RenderSettings,
    pub width: usize,
    pub height: usize,
    pub tiles_x: usize,
    pub tiles_y: usize,
    /// Camera centre (world).
    pub centre: [T; 3],
    /// `W = R_world_from_cam K⁻¹` (row-major).
    pub pix_to_dir: [T; 9],
    pub prims: Vec<PrimView<T>>,
    /// Visible primitives, front to back.
    pub order: Vec<u32>,
    /// Per tile (row-major over tiles), primitive indices front to back.
    pub tile_lists: Vec<Vec<u32>>,
    /// Evaluate the thermal image `F`. `false` (the G-buffers only, for a view whose image does
    /// not enter the loss): the thermal plane stays zero and no band phase is evaluated; every
    /// G-buffer, and every gradient given a zero thermal upstream, is unchanged.
    pub thermal: bool,
}

impl<T: Copy> Prepared<T> {
    /// A copy with the shortcuts off: every primitive through `pow` and every one of the
    /// `bands` slots evaluated (outputs unchanged while dropped slots hold zeros; dropped slots
    /// then get gradients). For benchmarks and for tests of the shortcuts' exactness.
    pub fn without_shortcuts(&self, bands: usize) -> Self {
        let mut out = self.clone();
        for pv in &mut out.prims {
            pv.gaussian = false;
            pv.live_bands = bands;
        }
        out
    }
}

impl<T> Prepared<T> {
    /// Tile index of pixel `(x, y)`.
    pub fn tile_of(&self, x: usize, y: usize) -> usize {
        (y / TILE_SIZE) * self.tiles_x + x / TILE_SIZE
    }
}

/// Builds the per-view data (validates shapes first).
// Why this stays long: the CPU reference of `raster_project.glsl` and the binning after it,
// step for step in the shader's order (validation, projection, 2-D extent, bands, tiles), so a
// parity failure points at the same line in both.
pub fn prepare<T: Real>(
    prims: &Primitives<T>,
    cam: &PinholeCamera,
    settings: &RenderSettings,
) -> Result<Prepared<T>, RenderError> {
    prims.validate()?;
    cam.validate()?;
    let f = T::from_f64;
    let width = cam.width;
    let height = cam.height;
    let tiles_x = width.div_ceil(TILE_SIZE);
    let tiles_y = height.div_ceil(TILE_SIZE);
    let c64 = cam.centre_world();
    let centre = c64.map(f);
    let w64 = cam.pixel_to_world_dir();
    let pix_to_dir = w64.map(f);
    let k = prims.sh_k();

    // Each primitive's view data alone: in parallel, the same on any number of threads.
    let views: Vec<PrimView<T>> = (0..prims.len())
        .into_par_iter()
        .map(|i| {
            let mut pv = PrimView::<T>::default();
            let mu = prims.mean(i);
            let (rot, unit_quat, quat_norm) = rotation_from_quat(prims.quat(i));
            let scales = prims.scales(i);
            let inv_s = scales.map(|s| T::ONE / s);
            // N = diag(1/s) Rᵀ: row i of N is column i of R divided by s_i.
            let mut n_mat = [T::ZERO; 9];
            for r in 0..3 {
                for c in 0..3 {
                    n_mat[3 * r + c] = rot[3 * c + r] * inv_s[r];
                }
            }
            let c_minus_mu = v3::sub(centre, mu);
            let a = v3::mat_vec(&n_mat, c_minus_mu);
            let b_mat = v3::mat_mul(&n_mat, &pix_to_dir);
            let (opacity, d_opacity) = prims.opacity(i);
            let (beta, d_beta) = prims.beta(i);
            let m = prims.bands;
            let live_bands = prims.live_bands(i);
            let psi_high =
                (0..live_bands).fold(T::ZERO, |acc, j| acc + prims.band_amp[m * i + j].abs());
            let (sh_dir, sh_norm) = sh::normalize(v3::sub(mu, centre));
            let colour = if k > 0 {
                sh::eval(&prims.sh[3 * k * i..3 * k * (i + 1)], k, sh_dir).0
            } else {
                [T::ZERO; 3]
            };

            let mu64 = mu.map(|x| x.to_f64());
            let mu_cam = cam.to_cam(mu64);
            let finite = n_mat
                .iter()
                .chain(a.iter())
                .chain(b_mat.iter())
                .all(|x| x.is_finite())
                && opacity.is_finite()
                && beta.is_finite();
            let o64 = opacity.to_f64();
            pv.visible = finite && mu_cam[2] > settings.near_m && o64 >= ALPHA_MIN;
            pv.depth_z_m = mu_cam[2];
            if pv.visible {
                let s64 = scales.map(|s| s.to_f64());
                let rot64 = rot.map(|x| x.to_f64());
                pv.bbox_px = cull_box(cam, settings, mu_cam, &rot64, s64, o64);
                pv.tile_rect = tile_rect(pv.bbox_px, width, height, settings.cull);
            }
            pv.n_mat = n_mat;
            pv.a = a;
            pv.b_mat = b_mat;
            pv.c_minus_mu = c_minus_mu;
            pv.rot = rot;
            pv.unit_quat = unit_quat;
            pv.quat_norm = quat_norm;
            pv.scales = scales;
            pv.opacity = opacity;
            pv.d_opacity = d_opacity;
            pv.beta = beta;
            pv.d_beta = d_beta;
            pv.gaussian = beta == T::TWO;
            pv.live_bands = live_bands;
            pv.psi_high = psi_high;
            pv.colour = colour;
            pv.sh_dir = sh_dir;
            pv.sh_norm = sh_norm;
            pv
        })
        .collect();

    let mut order: Vec<u32> = (0..views.len())
        .filter(|&i| views[i].visible)
        .filter_map(|i| u32::try_from(i).ok())
        .collect();
    order.sort_by(|&x, &y| {
        views[x as usize]
            .depth_z_m
            .total_cmp(&views[y as usize].depth_z_m)
    });

    let mut tile_lists = vec![Vec::new(); tiles_x * tiles_y];
    for &i in &order {
        let [tx0, ty0, tx1, ty1] = views[i as usize].tile_rect;
        for ty in ty0..ty1 {
            for tx in tx0..tx1 {
                tile_lists[ty * tiles_x + tx].push(i);
            }
        }
    }

    Ok(Prepared {
        settings: *settings,
        width,
        height,
        tiles_x,
        tiles_y,
        centre,
        pix_to_dir,
        prims: views,
        order,
        tile_lists,
        thermal: true,
    })
}

/// Padded pixel box of the silhouette of the culling ellipsoid (see the parent module).
fn cull_box(
    cam: &PinholeCamera,
    settings: &RenderSettings,
    mu_cam: [f64; 3],
    rot: &[f64; 9],
    s: [f64; 3],
    opacity: f64,
) -> [f64; 4] {
    let full = [
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::INFINITY,
    ];
    let l = (255.0 * opacity).ln();
    let r2 = l.max(1.0);
    // Σ_cam = (R_cw R) diag(s²) (R_cw R)ᵀ, scaled by r².
    let rcw = cam.rotation_cam_from_world();
    let m = v3::mat_mul(&rcw, rot);
    let mut e = [0.0f64; 9];
    for i in 0..3 {
        for j in 0..3 {
            e[3 * i + j] = r2
                * (m[3 * i] * m[3 * j] * s[0] * s[0]
                    + m[3 * i + 1] * m[3 * j + 1] * s[1] * s[1]
                    + m[3 * i + 2] * m[3 * j + 2] * s[2] * s[2]);
        }
    }
    let z_extent = e[8].sqrt();
    let clear_of_near = mu_cam[2] - z_extent > settings.near_m; // false for NaN
    if !clear_of_near {
        return full;
    }
    // D = E − μμᵀ; C* = K D Kᵀ.
    let mut d = e;
    for i in 0..3 {
        for j in 0..3 {
            d[3 * i + j] -= mu_cam[i] * mu_cam[j];
        }
    }
    let k = [
        cam.fx_px, 0.0, cam.cx_px, 0.0, cam.fy_px, cam.cy_px, 0.0, 0.0, 1.0,
    ];
    let kd = v3::mat_mul(&k, &d);
    let kt = [k[0], k[3], k[6], k[1], k[4], k[7], k[2], k[5], k[8]];
    let cs = v3::mat_mul(&kd, &kt);
    let c22 = cs[8];
    let ellipse = c22 < 0.0; // false for NaN
    if !ellipse {
        return full;
    }
    let range = |c_aa: f64, c_a2: f64| -> Option<(f64, f64)> {
        let disc = (c_a2 * c_a2 - c_aa * c22).max(0.0).sqrt();
        let x0 = (c_a2 + disc) / c22;
        let x1 = (c_a2 - disc) / c22;
        let (lo, hi) = (x0.min(x1), x0.max(x1));
        let pad = CULL_PAD_PX + 1e-9 * (lo.abs().max(hi.abs()));
        if lo.is_finite() && hi.is_finite() {
            Some((lo - pad, hi + pad))
        } else {
            None
        }
    };
    match (range(cs[0], cs[2]), range(cs[4], cs[5])) {
        (Some((u0, u1)), Some((v0, v1))) => [u0, v0, u1, v1],
        _ => full,
    }
}

/// Tiles whose pixel centres meet the box (all tiles when culling is off).
fn tile_rect(b: [f64; 4], width: usize, height: usize, cull: bool) -> [usize; 4] {
    let tx = width.div_ceil(TILE_SIZE);
    let ty = height.div_ceil(TILE_SIZE);
    if !cull {
        return [0, 0, tx, ty];
    }
    let [u0, v0, u1, v1] = b;
    let (wmax, hmax) = ((width - 1) as f64, (height - 1) as f64);
    if u1 < 0.0 || v1 < 0.0 || u0 > wmax || v0 > hmax {
        return [0, 0, 0, 0];
    }
    let t = TILE_SIZE as f64;
    let lo = |x: f64| (x.max(0.0) / t).floor() as usize;
    let hi = |x: f64, max: f64, n: usize| ((x.min(max) / t).floor() as usize + 1).min(n);
    [lo(u0), lo(v0), hi(u1, wmax, tx), hi(v1, hmax, ty)]
}
