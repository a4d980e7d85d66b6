//! Thermal gradient alignment (TGA-GS §3.4): `L_thermal-align = Σ_i ‖∇T_i · n_i‖₁`, the observed
//! thermal image's gradient at pixel i dotted with the rendered unit surface normal, with its
//! exact gradient w.r.t. the rendered depth and alpha planes.
//!
//! # Definition
//! - **Normals from the depth G-buffer**, not from each primitive's shortest axis: S³-TIR
//!   primitives are not flattened (their shortest axis is not a surface normal), the depth
//!   G-buffer is what the mesh stage fuses, and both backends' backward passes already take
//!   depth and alpha gradients. Expected depth `D_p = depth_p / alpha_p` (`depth` is the
//!   alpha-weighted `Σ w t*`) where `alpha_p ≥ min_alpha` ([`AlignSettings`]) and `D_p` is finite
//!   and `≥ 0`; other pixels are invalid.
//! - Back-projection with [`PinholeCamera`]'s convention (pixel `(x, y)` is the ray through
//!   `(u, v) = (x, y)`, origin at the centre of the top-left pixel):
//!   `P_p = D_p · ((u − cx)/fx, (v − cy)/fy, 1)`, camera frame (x right, y down, z forward).
//! - Tangents by forward differences `t_u = P(u+1, v) − P(u, v)`, `t_v = P(u, v+1) − P(u, v)`,
//!   normal `n = (t_u × t_v) / ‖t_u × t_v‖`. It points away from the camera: for positive depths
//!   `(t_u × t_v) · P_p = D_p D_{u+1} D_{v+1} / (fx fy) > 0` exactly (the terms along the rays
//!   cancel in the triple product), so the tangents are never parallel unless a depth is 0.
//! - Pixel `p` **contributes** only if it and both forward neighbours are valid (so the last
//!   column and row never do), the relative depth step to each neighbour
//!   `|D_q − D_p| ≤ max_depth_step · min(D_p, D_q)` (larger steps are occlusion boundaries, not
//!   surfaces), and the tangents are not degenerate: `‖t_u × t_v‖ > MIN_TANGENT_SINE·‖t_u‖‖t_v‖`
//!   ([`MIN_TANGENT_SINE`]; only reachable with zero or underflowing depths). These masks are
//!   constants of the loss, like the renderer's α cut: no gradient flows through them.
//! - Thermal gradient of the **target** (observed) image, which gets no gradient: central
//!   differences `g = ((T(u+1) − T(u−1))/2, (T(v+1) − T(v−1))/2)`, one-sided at the borders, 0
//!   along an axis of length 1 ([`thermal_gradient`]); lifted into the camera frame as
//!   `(gx, gy, 0)` (the image axes are the camera's x and y).
//! - `L = weight · (1/(W·H)) · Σ_p |gx·nx + gy·ny|`, normalised by the pixel count, not the
//!   contributing count, so the loss does not jump when pixels enter or leave the masks;
//!   subgradient `sign(0) = 0`.
//!
//! # What it does to the geometry
//! `gx·nx + gy·ny = n · (gx, gy, 0) = 0` exactly when the 3-D direction `(gx, gy, 0)`, the thermal
//! gradient laid parallel to the image plane, is tangent to the surface: crossing the thermal
//! edge, the surface keeps its camera depth. A pixel costs `|∇T| · |cos ∠(n, (ĝ, 0))|`. So
//! wherever the target has thermal edges the loss pulls the rendered surface towards **facing
//! the camera** (fronto-parallel) or **tilting only along the edge** (about an axis along the
//! gradient); a tilt about an axis parallel to the edge (depth changing across the edge) is
//! penalised in proportion to the thermal contrast. It is a view-dependent flattening prior
//! across thermal edges, not a term that puts creases or depth edges at thermal edges: a real
//! crease between two faces of different temperature is penalised unless both faces are flat
//! across it as seen from this camera, and true occlusion edges (> `max_depth_step`) are
//! masked rather than encouraged. The paper's wording ("aligning thermal and geometric
//! boundaries") suggests more than the formula does; the trainer's ablation measures whether it
//! helps. `loss` is in target units (inputs normalised to [0, 1] per scene).
//!
//! # Gradient
//! With `s = g·n`, `c = t_u × t_v`: `∂|s|/∂c = sign(s)·(g − s·n)/‖c‖ =: a`,
//! `∂/∂P(u+1,v) = t_v × a`, `∂/∂P(u,v+1) = a × t_u`, `∂/∂P(u,v) = −(both)`; `∂/∂D_q = ray_q · ∂/∂P_q`;
//! `∂D/∂depth = 1/alpha`, `∂D/∂alpha = −D/alpha`. The gradient scales like `1/D` (the normal is
//! invariant to a common scale of the depths).
//!
//! # Threads
//! Rows run on rayon's pool. Each row writes its pixels' contributions to its own row and, in a
//! separate array, to the row below; per-row loss sums are added in row order and the two arrays
//! are combined serially, so the result is bit-identical on any number of threads.

use rayon::prelude::*;

use super::check_len;
use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::real::Real;
use crate::render::GBuffers;

/// Tangents whose cross product is at most this fraction of `‖t_u‖·‖t_v‖` (the sine of their
/// angle) are degenerate and the pixel is skipped (f32 resolves the sine to ~1e-7).
pub const MIN_TANGENT_SINE: f64 = 1e-6;

/// Masks of [`thermal_align`] and [`normals`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignSettings {
    /// Pixels with accumulated alpha below this have no depth.
    pub min_alpha: f64,
    /// Largest relative depth step to a forward neighbour that is still a surface
    /// (`|ΔD| ≤ max_depth_step · min(D_p, D_q)`).
    pub max_depth_step: f64,
}

impl Default for AlignSettings {
    fn default() -> Self {
        Self {
            min_alpha: 0.5,
            max_depth_step: 0.1,
        }
    }
}

/// Value of the weighted loss and the number of pixels that passed every mask (including those
/// where `∇T · n` is 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignLoss {
    pub loss: f64,
    pub pixels: usize,
}

/// A contributing pixel's normal and what its gradient needs.
struct PixelNormal<T> {
    n: [T; 3],
    c_norm: T,
    t_u: [T; 3],
    t_v: [T; 3],
}

/// Expected depths and pixel rays of one view.
struct DepthFrame<T> {
    width: usize,
    height: usize,
    /// `D_p`, `None` where invalid.
    depths: Vec<Option<T>>,
    /// `(x − cx)/fx` per column.
    ray_x: Vec<T>,
    /// `(y − cy)/fy` per row.
    ray_y: Vec<T>,
    max_step: T,
}

impl<T: Real> DepthFrame<T> {
    fn new(
        rendered: &GBuffers<T>,
        camera: &PinholeCamera,
        settings: &AlignSettings,
    ) -> Result<Self, RenderError> {
        let (w, h) = (rendered.width, rendered.height);
        camera.validate()?;
        if camera.width != w || camera.height != h {
            return Err(RenderError::InvalidCamera {
                camera: "thermal_align",
                reason: "camera size differs from the rendered buffers",
            });
        }
        check_len("rendered.depth", rendered.depth.len(), w, h)?;
        check_len("rendered.alpha", rendered.alpha.len(), w, h)?;
        let min_alpha = T::from_f64(settings.min_alpha);
        let depths = rendered
            .depth
            .iter()
            .zip(&rendered.alpha)
            .map(|(&depth, &alpha)| {
                if alpha >= min_alpha && alpha > T::ZERO {
                    let d = depth / alpha;
                    (d.is_finite() && d >= T::ZERO).then_some(d)
                } else {
                    None
                }
            })
            .collect();
        Ok(Self {
            width: w,
            height: h,
            depths,
            ray_x: (0..w)
                .map(|x| T::from_f64((x as f64 - camera.cx_px) / camera.fx_px))
                .collect(),
            ray_y: (0..h)
                .map(|y| T::from_f64((y as f64 - camera.cy_px) / camera.fy_px))
                .collect(),
            max_step: T::from_f64(settings.max_depth_step),
        })
    }

    fn ray(&self, x: usize, y: usize) -> [T; 3] {
        [self.ray_x[x], self.ray_y[y], T::ONE]
    }

    /// `|a − b| ≤ max_step · min(a, b)` (false for NaN).
    fn step_ok(&self, a: T, b: T) -> bool {
        (a - b).abs() <= self.max_step * a.min(b)
    }

    /// Normal of pixel `(x, y)` if it passes every mask.
    fn pixel_normal(&self, x: usize, y: usize) -> Option<PixelNormal<T>> {
        if x + 1 >= self.width || y + 1 >= self.height {
            return None;
        }
        let p = y * self.width + x;
        let d0 = self.depths[p]?;
        let dr = self.depths[p + 1]?;
        let dd = self.depths[p + self.width]?;
        if !(self.step_ok(d0, dr) && self.step_ok(d0, dd)) {
            return None;
        }
        let p0 = scale(self.ray(x, y), d0);
        let t_u = sub(scale(self.ray(x + 1, y), dr), p0);
        let t_v = sub(scale(self.ray(x, y + 1), dd), p0);
        let c = cross(t_u, t_v);
        let c_norm = dot(c, c).sqrt();
        let limit = T::from_f64(MIN_TANGENT_SINE) * dot(t_u, t_u).sqrt() * dot(t_v, t_v).sqrt();
        let spans = c_norm > limit; // false for NaN and for 0 > 0 (coincident points)
        if !spans {
            return None;
        }
        Some(PixelNormal {
            n: scale(c, T::ONE / c_norm),
            c_norm,
            t_u,
            t_v,
        })
    }
}

/// Central differences of `target` along x and y (one-sided at the borders, 0 along an axis of
/// length 1), row-major like the image.
pub fn thermal_gradient<T: Real>(
    target: &[T],
    width: usize,
    height: usize,
) -> Result<(Vec<T>, Vec<T>), RenderError> {
    check_len("target", target.len(), width, height)?;
    let n = width * height;
    let mut gx = vec![T::ZERO; n];
    let mut gy = vec![T::ZERO; n];
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            gx[p] = diff(target, p, x, width, 1);
            gy[p] = diff(target, p, y, height, width);
        }
    }
    Ok((gx, gy))
}

/// Difference at index `i` of an axis of length `len` whose neighbours are `stride` apart.
fn diff<T: Real>(v: &[T], p: usize, i: usize, len: usize, stride: usize) -> T {
    if len < 2 {
        T::ZERO
    } else if i == 0 {
        v[p + stride] - v[p]
    } else if i + 1 == len {
        v[p] - v[p - stride]
    } else {
        (v[p + stride] - v[p - stride]) * T::HALF
    }
}

/// Camera-frame unit normals of the depth G-buffer (`None` where a pixel does not pass the
/// masks), as [`thermal_align`] uses them.
pub fn normals<T: Real>(
    rendered: &GBuffers<T>,
    camera: &PinholeCamera,
    settings: &AlignSettings,
) -> Result<Vec<Option<[T; 3]>>, RenderError> {
    let frame = DepthFrame::new(rendered, camera, settings)?;
    let w = frame.width;
    Ok((0..w * frame.height)
        .map(|p| frame.pixel_normal(p % w, p / w).map(|pn| pn.n))
        .collect())
}

/// `L_thermal-align` of the rendered depth against the observed thermal image `target`; adds
/// `dL/d(depth)` and `dL/d(alpha)` into `upstream.depth` / `upstream.alpha` (`weight` included).
pub fn thermal_align<T: Real>(
    rendered: &GBuffers<T>,
    target: &[T],
    camera: &PinholeCamera,
    settings: &AlignSettings,
    weight: f64,
    upstream: &mut GBuffers<T>,
) -> Result<AlignLoss, RenderError> {
    let frame = DepthFrame::new(rendered, camera, settings)?;
    let (w, h) = (frame.width, frame.height);
    check_len("upstream.depth", upstream.depth.len(), w, h)?;
    check_len("upstream.alpha", upstream.alpha.len(), w, h)?;
    let (gx, gy) = thermal_gradient(target, w, h)?;
    let n_px = w * h;
    let k = T::from_f64(weight / n_px as f64);
    // dL/dD: contributions of row y's pixels to row y, and to row y + 1 (stored at the source).
    let mut own = vec![T::ZERO; n_px];
    let mut below = vec![T::ZERO; n_px];
    let rows: Vec<(f64, usize)> = own
        .par_chunks_mut(w)
        .zip(below.par_chunks_mut(w))
        .enumerate()
        .map(|(y, (own_row, below_row))| {
            let mut sum = 0.0;
            let mut pixels = 0;
            for x in 0..w {
                let Some(pn) = frame.pixel_normal(x, y) else {
                    continue;
                };
                pixels += 1;
                let p = y * w + x;
                let g = [gx[p], gy[p], T::ZERO];
                let s = dot(g, pn.n);
                sum += s.abs().to_f64();
                let sign = s.sign0();
                if sign == T::ZERO {
                    continue;
                }
                let a = scale(sub(g, scale(pn.n, s)), k * sign / pn.c_norm);
                let d_right = cross(pn.t_v, a);
                let d_down = cross(a, pn.t_u);
                let d_here = scale(add(d_right, d_down), -T::ONE);
                own_row[x] += dot(frame.ray(x, y), d_here);
                own_row[x + 1] += dot(frame.ray(x + 1, y), d_right);
                below_row[x] = dot(frame.ray(x, y + 1), d_down);
            }
            (sum, pixels)
        })
        .collect();
    let mut sum = 0.0;
    let mut pixels = 0;
    for (s, c) in rows {
        sum += s;
        pixels += c;
    }
    for q in 0..n_px {
        let mut g_d = own[q];
        if q >= w {
            g_d += below[q - w];
        }
        let Some(d) = frame.depths[q] else {
            continue;
        };
        if g_d == T::ZERO {
            continue;
        }
        let alpha = rendered.alpha[q];
        upstream.depth[q] += g_d / alpha;
        upstream.alpha[q] -= g_d * d / alpha;
    }
    Ok(AlignLoss {
        loss: weight * sum / n_px as f64,
        pixels,
    })
}

#[inline]
fn dot<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn add<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
fn sub<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn scale<T: Real>(a: [T; 3], s: T) -> [T; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
fn cross<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn camera(w: usize, h: usize, f: f64) -> PinholeCamera {
        PinholeCamera::look_at([0.0; 3], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], f, w, h)
    }

    /// Buffers of the plane `n·P = 1` (camera frame) with alpha 0.8.
    fn plane(cam: &PinholeCamera, n: [f64; 3]) -> GBuffers<f64> {
        let (w, h) = (cam.width, cam.height);
        let mut g = GBuffers::zeros(w, h, false);
        for y in 0..h {
            for x in 0..w {
                let r = [
                    (x as f64 - cam.cx_px) / cam.fx_px,
                    (y as f64 - cam.cy_px) / cam.fy_px,
                    1.0,
                ];
                let p = y * w + x;
                g.alpha[p] = 0.8;
                g.depth[p] = 0.8 / dot(n, r);
            }
        }
        g
    }

    #[test]
    fn gradient_of_a_ramp_is_exact_including_borders() {
        let (w, h) = (5, 4);
        let t: Vec<f64> = (0..w * h)
            .map(|p| 0.3 * (p % w) as f64 - 0.7 * (p / w) as f64)
            .collect();
        let (gx, gy) = thermal_gradient(&t, w, h).unwrap();
        assert!(
            gx.iter().all(|v| (v - 0.3).abs() < 1e-12)
                && gy.iter().all(|v| (v + 0.7).abs() < 1e-12),
            "a ramp 0.3·x − 0.7·y has gradient (0.3, −0.7) everywhere: {gx:?} {gy:?}"
        );
        let (gx1, _) = thermal_gradient(&[1.0, 2.0, 3.0], 1, 3).unwrap();
        assert_eq!(gx1, vec![0.0; 3], "an axis of length 1 has no gradient");
        assert!(
            thermal_gradient(&t, w, h + 1).is_err(),
            "a target of the wrong size is an error"
        );
    }

    #[test]
    fn normals_of_planes_are_the_plane_normal() {
        let cam = camera(9, 7, 10.0);
        for n in [[0.0, 0.0, 0.25], [0.05, -0.03, 0.3], [-0.1, 0.02, 0.2]] {
            let nn = dot(n, n).sqrt();
            let normals = normals(&plane(&cam, n), &cam, &AlignSettings::default()).unwrap();
            let mut count = 0;
            for (p, v) in normals.iter().enumerate() {
                let (x, y) = (p % 9, p / 9);
                if x == 8 || y == 6 {
                    assert!(v.is_none(), "last column/row has no forward neighbour");
                    continue;
                }
                let v = v.expect("every inner pixel of a plane has a normal");
                count += 1;
                for i in 0..3 {
                    assert!(
                        (v[i] - n[i] / nn).abs() < 1e-12,
                        "pixel {p}: normal {v:?}, want the plane's {n:?}/‖n‖ (away from the camera)"
                    );
                }
            }
            assert_eq!(count, 8 * 6);
        }
    }

    #[test]
    fn same_bits_on_any_thread_count() {
        let cam = camera(33, 21, 30.0);
        let mut g = plane(&cam, [0.04, 0.02, 0.3]);
        for (p, d) in g.depth.iter_mut().enumerate() {
            *d *= 1.0 + 0.01 * (p as f64 * 0.37).sin();
        }
        let target: Vec<f64> = (0..33 * 21).map(|p| (p as f64 * 0.71).cos()).collect();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut up = GBuffers::zeros(33, 21, false);
                let l = thermal_align(&g, &target, &cam, &AlignSettings::default(), 0.3, &mut up)
                    .unwrap();
                (l.loss.to_bits(), l.pixels, up)
            })
        };
        let one = run(1);
        assert!(
            one.1 > 0 && one.0 != 0,
            "the scene must have contributing pixels"
        );
        for threads in [2, 5] {
            let other = run(threads);
            assert!(
                other.0 == one.0 && other.1 == one.1,
                "{threads} threads: loss/pixel count differ from 1 thread"
            );
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&other.2.depth),
                bits(&one.2.depth),
                "{threads} threads: depth gradient bits"
            );
            assert_eq!(
                bits(&other.2.alpha),
                bits(&one.2.alpha),
                "{threads} threads: alpha gradient bits"
            );
        }
    }

    #[test]
    fn size_mismatches_are_errors() {
        let cam = camera(6, 5, 8.0);
        let g = plane(&cam, [0.0, 0.0, 0.3]);
        let target = vec![0.0; 30];
        let s = AlignSettings::default();
        let mut up = GBuffers::zeros(6, 5, false);
        assert!(
            thermal_align(&g, &target[..29], &cam, &s, 1.0, &mut up).is_err(),
            "short target must be refused"
        );
        assert!(
            thermal_align(&g, &target, &camera(6, 4, 8.0), &s, 1.0, &mut up).is_err(),
            "camera of another size must be refused"
        );
        let mut short = GBuffers::zeros(6, 5, false);
        short.alpha.pop();
        assert!(
            thermal_align(&g, &target, &cam, &s, 1.0, &mut short).is_err(),
            "short upstream alpha must be refused"
        );
    }
}
