//! Sub-pixel chessboard corners by fitting a blurred-saddle model to the pixels around each
//! corner (the saddle-point fit).
//!
//! # Model
//! Near an inner corner the board shows two straight edges crossing at the corner (a
//! perspective view maps the board's lines to lines; lens distortion bends them negligibly
//! over a few pixels), with the four squares alternating. The image is modelled as
//!
//! ```text
//! I(p) = m + g·(p − w) + c · tanh(n₁·(p − x₀) / s) · tanh(n₂·(p − x₀) / s)
//! ```
//!
//! with corner `x₀`, edge normals `n₁ = (cos a₁, sin a₁)` and `n₂ = (cos a₂, sin a₂)` (the two
//! edges need not be perpendicular), edge width `s` (optics, pixel integration and, for
//! thermal images, lateral heat conduction; `tanh` is a stand-in for the edge profile, whose
//! exact shape does not move a symmetric corner), square contrast `c` (either sign), mean `m`
//! and a linear trend `g` about the window centre `w` (vignetting, a board temperature
//! gradient). The nine parameters are fitted by Levenberg–Marquardt to the pixel values in a
//! window around the starting corner, with weights tapering to zero at its rim. The window is
//! the parallelogram reaching 0.7 of the way to the neighbouring corners along the row and the
//! column (inside it the four-square model holds up to the edge blur), at most
//! [`MAX_RADIUS_PX`] along each.
//!
//! # Why
//! `cornerSubPix` solves for the point where the image gradients are orthogonal to the
//! directions to it; with 5–7 px squares (a Lepton at 160×120 seeing a board at ~1 m) its
//! window holds a few dozen pixels, most gradient-free, and it has to run on a cubic-upscaled
//! copy whose interpolation adds its own ripple. The model fit uses every pixel's value at its
//! true position (no resampling) and weighs them as a least-squares estimator does, which is
//! what the noise of a thermal core calls for. On large, sharp RGB squares the two agree.
//!
//! The fit is *rejected* (the caller keeps its previous corner) when it does not converge, moves
//! the corner by more than a third of the window's half-size, or finds no contrast (|c| below
//! 4× the residual RMS). The edge width is kept within 0.15 px and half the corner spacing.
//!
//! [`fit_saddle`] runs in steps: the window and its weighted pixels (`Window`), the starting
//! parameters (the linear ones by least squares), the Levenberg–Marquardt iteration
//! (`Problem`) and the plausibility check above (`Window::accept`).

use glam::DVec2;
use nalgebra::{SMatrix, SVector};

/// Largest fit radius: large, sharp squares gain nothing from more pixels.
pub const MAX_RADIUS_PX: f64 = 7.0;
/// Smallest usable radius (below it the window holds too few pixels for nine parameters).
pub const MIN_RADIUS_PX: f64 = 1.8;

/// A single-channel float image borrowed row-major (pixel centres at integer coordinates).
#[derive(Debug, Clone, Copy)]
pub struct FloatImage<'a> {
    pub width_px: usize,
    pub height_px: usize,
    pub values: &'a [f32],
}

/// A successful fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SaddleFit {
    pub corner_px: DVec2,
    /// Fitted edge width `s`, pixels.
    pub edge_width_px: f64,
    /// Fitted square contrast `c` (image units).
    pub contrast: f64,
    /// Weighted RMS residual (image units).
    pub residual_rms: f64,
    pub iterations: usize,
}

const NP: usize = 9;
type Vec9 = SVector<f64, NP>;
type Mat9 = SMatrix<f64, NP, NP>;

struct Pixel {
    p: DVec2,
    value: f64,
    weight: f64,
}

/// The parameter-dependent constants of [`eval`], computed once per parameter vector.
struct Pre {
    x0: f64,
    y0: f64,
    s: f64,
    c1: f64,
    s1: f64,
    c2: f64,
    s2: f64,
}

impl Pre {
    fn new(params: &Vec9) -> Self {
        let (s1, c1) = params[2].sin_cos();
        let (s2, c2) = params[3].sin_cos();
        Self {
            x0: params[0],
            y0: params[1],
            s: params[4].exp(),
            c1,
            s1,
            c2,
            s2,
        }
    }
}

/// Model value and gradient with respect to the parameters
/// `[x₀, y₀, a₁, a₂, ln s, m, c, gₓ, g_y]`.
fn eval(params: &Vec9, pre: &Pre, centre: DVec2, p: DVec2) -> (f64, Vec9) {
    let Pre {
        x0,
        y0,
        s,
        c1,
        s1,
        c2,
        s2,
    } = *pre;
    let (m, c, gx, gy) = (params[5], params[6], params[7], params[8]);
    let q = p - DVec2::new(x0, y0);
    let d1 = c1 * q.x + s1 * q.y;
    let d2 = c2 * q.x + s2 * q.y;
    let t1 = tanh(d1 / s);
    let t2 = tanh(d2 / s);
    let dt1 = (1.0 - t1 * t1) / s; // ∂t₁/∂d₁
    let dt2 = (1.0 - t2 * t2) / s;
    let w = p - centre;
    let value = m + gx * w.x + gy * w.y + c * t1 * t2;
    let mut g = Vec9::zeros();
    // ∂d/∂x₀ = −cos a, ∂d/∂y₀ = −sin a.
    g[0] = c * (t2 * dt1 * -c1 + t1 * dt2 * -c2);
    g[1] = c * (t2 * dt1 * -s1 + t1 * dt2 * -s2);
    g[2] = c * t2 * dt1 * (-s1 * q.x + c1 * q.y);
    g[3] = c * t1 * dt2 * (-s2 * q.x + c2 * q.y);
    // ∂t/∂ln s = (1 − t²)·(−d/s) = −dt·d.
    g[4] = c * (t2 * -dt1 * d1 + t1 * -dt2 * d2);
    g[5] = 1.0;
    g[6] = t1 * t2;
    g[7] = w.x;
    g[8] = w.y;
    (value, g)
}

/// Sub-samples per pixel axis for the pixel-area average: enough that the samples are no
/// further apart than the width of an edge's transition (≈ 2·s): 1 for edges ≥ 0.6 px wide,
/// whose profile is smooth across a pixel, 2 down to 0.3 px, up to 4 for the sharpest
/// (0.15 px, the floor). So the average varies smoothly with the corner position instead of in
/// coverage steps. Measured on the sun-board RGB photos (edges at the floor): 8 sub-samples
/// instead of 4 change the RGB camera's RMS by 0.00004 px and cost 1.6× the detection time.
fn subsamples(edge_width_px: f64) -> usize {
    (0.6 / edge_width_px.max(1e-3)).ceil().clamp(1.0, 4.0) as usize
}

/// The model averaged over a pixel's area (a pixel integrates light over its whole surface;
/// sampling the model at the pixel centre alone makes the cost a staircase in the corner
/// position as soon as the edges are sharper than a pixel), with `n × n` sub-samples.
///
/// Only pixels that an edge's blur reaches are sub-sampled: where both edges are more than
/// half a pixel diagonal plus [`FLAT_EDGE_WIDTHS`] edge widths from the pixel centre, the model
/// is flat across the pixel (`tanh` within 1e-4 of ±1 on its whole area) and its centre value
/// is its average to that precision. On sharp RGB edges (width at the 0.15 px floor) this is
/// most of the window: the sun-board detection went from 16.7 s to 10.9 s with it (then with
/// 8 × 8 sub-samples).
fn eval_pixel(params: &Vec9, pre: &Pre, centre: DVec2, p: DVec2, n: usize) -> (f64, Vec9) {
    if n > 1 {
        let q = p - DVec2::new(pre.x0, pre.y0);
        let d1 = pre.c1 * q.x + pre.s1 * q.y;
        let d2 = pre.c2 * q.x + pre.s2 * q.y;
        let reach = std::f64::consts::FRAC_1_SQRT_2 + FLAT_EDGE_WIDTHS * pre.s;
        if d1.abs() > reach && d2.abs() > reach {
            return eval(params, pre, centre, p);
        }
    }
    let mut value = 0.0;
    let mut grad = Vec9::zeros();
    let step = 1.0 / n as f64;
    for sy in 0..n {
        let dy = (sy as f64 + 0.5) * step - 0.5;
        for sx in 0..n {
            let dx = (sx as f64 + 0.5) * step - 0.5;
            let (v, g) = eval(params, pre, centre, p + DVec2::new(dx, dy));
            value += v;
            grad += g;
        }
    }
    let count = (n * n) as f64;
    (value / count, grad / count)
}

/// Edge widths beyond which a pixel is flat enough to skip its sub-samples (`tanh 5` is
/// within 1e-4 of 1).
const FLAT_EDGE_WIDTHS: f64 = 5.0;

/// The model's value alone (no gradient), averaged over the pixel as [`eval_pixel`] does: what
/// the cost of a trial step needs.
fn value_pixel(params: &Vec9, pre: &Pre, centre: DVec2, p: DVec2, n: usize) -> f64 {
    let (m, c, gx, gy) = (params[5], params[6], params[7], params[8]);
    let w = p - centre;
    let linear = m + gx * w.x + gy * w.y;
    let distances = |p: DVec2| {
        let q = p - DVec2::new(pre.x0, pre.y0);
        (pre.c1 * q.x + pre.s1 * q.y, pre.c2 * q.x + pre.s2 * q.y)
    };
    let at = |p: DVec2| {
        let (d1, d2) = distances(p);
        tanh(d1 / pre.s) * tanh(d2 / pre.s)
    };
    let (d1, d2) = distances(p);
    let reach = std::f64::consts::FRAC_1_SQRT_2 + FLAT_EDGE_WIDTHS * pre.s;
    if n <= 1 || (d1.abs() > reach && d2.abs() > reach) {
        return linear + c * at(p);
    }
    // The linear part averages to its centre value over the symmetric sub-sample grid.
    let step = 1.0 / n as f64;
    let mut sum = 0.0;
    for sy in 0..n {
        let dy = (sy as f64 + 0.5) * step - 0.5;
        for sx in 0..n {
            let dx = (sx as f64 + 0.5) * step - 0.5;
            sum += at(p + DVec2::new(dx, dy));
        }
    }
    linear + c * sum / (n * n) as f64
}

/// `tanh` through one `exp` (glibc's goes through `expm1` and is ~3× dearer; this is the
/// saddle fit's innermost call). Absolute error below 1e-15, except beyond |x| = 10, where it
/// is ±1 without an `exp` (error below 4.2e-9: far from both edges, where most of a sharp
/// edge's window lies).
fn tanh(x: f64) -> f64 {
    if x.abs() > 10.0 {
        return 1f64.copysign(x);
    }
    let e = (-2.0 * x.abs()).exp();
    ((1.0 - e) / (1.0 + e)).copysign(x)
}

fn cost(params: &Vec9, centre: DVec2, pixels: &[Pixel]) -> f64 {
    let n = subsamples(params[4].exp());
    let pre = Pre::new(params);
    pixels
        .iter()
        .map(|px| px.weight * (value_pixel(params, &pre, centre, px.p, n) - px.value).powi(2))
        .sum()
}

/// How the edge width `s` is treated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EdgeWidth {
    /// Fitted, starting from this value (px), for at most `max_iterations`; the result is
    /// returned even when not converged (it serves to estimate the image's edge width).
    Estimate {
        guess_px: f64,
        max_iterations: usize,
    },
    /// Held at this value (px): the corner fit proper.
    Fixed(f64),
}

/// Fits the saddle model around `start`. `step_a` and `step_b` are the grid steps at the
/// corner: the vectors to the next corner along a row and along a column (their directions
/// are the two board edges through the corner, their lengths the local spacing). `None` when
/// the fit is rejected (module docs).
///
/// The window is the parallelogram `|u|, |v| < 0.7` in grid coordinates
/// (`p − start = u·step_a + v·step_b`), capped at [`MAX_RADIUS_PX`] along each step: it holds
/// the four squares around the corner and, unlike a disc, keeps its pixels when the board is
/// strongly foreshortened along one axis.
///
/// The edge width is best held fixed at the image's typical value ([`EdgeWidth::Fixed`],
/// e.g. the median of [`EdgeWidth::Estimate`] fits over a board): fitted per corner, it can
/// drift for tens of iterations along a shallow valley where a sharp edge and a slightly
/// shifted corner explain the pixels almost equally well (thermal squares with
/// conduction-rounded interiors), and the corner drifts with it.
pub fn fit_saddle(
    img: FloatImage<'_>,
    start: DVec2,
    step_a: DVec2,
    step_b: DVec2,
    edge_width: EdgeWidth,
) -> Option<SaddleFit> {
    let (edge_width_guess_px, fit_width, max_iterations) = match edge_width {
        EdgeWidth::Estimate {
            guess_px,
            max_iterations,
        } => (guess_px, true, max_iterations),
        EdgeWidth::Fixed(s) => (s, false, 50),
    };
    let window = Window::new(start, step_a, step_b)?;
    let pixels = window.sample(img)?;
    let (s_min, s_max) = window.edge_width_bounds();
    let s0 = if fit_width {
        edge_width_guess_px.clamp(0.3, 0.25 * window.neighbour_px.max(1.2))
    } else {
        edge_width_guess_px.clamp(s_min, s_max)
    };
    let params = window.initial_params(s0, &pixels)?;
    let problem = Problem {
        centre: start,
        pixels: &pixels,
        fit_width,
        s_bounds: (s_min, s_max),
    };
    let end = problem.solve(params, max_iterations);
    if !end.converged && !fit_width {
        return None;
    }
    window.accept(&end, &pixels)
}

/// The fit window around a starting corner: the parallelogram `|u| < fa`, `|v| < fb` in grid
/// coordinates (`p − start = u·step_a + v·step_b`; [`fit_saddle`]).
struct Window {
    start: DVec2,
    step_a: DVec2,
    step_b: DVec2,
    /// `step_a × step_b`, the determinant of the grid coordinates.
    det: f64,
    /// Half-extent along `step_a`, grid units.
    fa: f64,
    /// Half-extent along `step_b`, grid units.
    fb: f64,
    /// The shorter step's length (px): the local corner spacing.
    neighbour_px: f64,
    /// Fit radius (px): the corner may move a third of it.
    radius: f64,
}

impl Window {
    /// The window at `start`; `None` when it is too small, `start` is not finite or the steps
    /// are nearly parallel.
    fn new(start: DVec2, step_a: DVec2, step_b: DVec2) -> Option<Self> {
        let (len_a, len_b) = (step_a.length(), step_b.length());
        let neighbour_px = len_a.min(len_b);
        let radius = (0.7 * neighbour_px).min(MAX_RADIUS_PX);
        let det = step_a.perp_dot(step_b);
        let regular = det.abs() > 0.2 * len_a * len_b;
        if radius.is_nan() || radius < MIN_RADIUS_PX || !start.is_finite() || !regular {
            return None;
        }
        // Window half-extent along each step, in grid units.
        let fa = 0.7f64.min(MAX_RADIUS_PX / len_a);
        let fb = 0.7f64.min(MAX_RADIUS_PX / len_b);
        Some(Self {
            start,
            step_a,
            step_b,
            det,
            fa,
            fb,
            neighbour_px,
            radius,
        })
    }

    /// The window's pixels with their taper weights; `None` when the window is cut by the
    /// image border, holds a non-finite value or too few pixels for the nine parameters.
    fn sample(&self, img: FloatImage<'_>) -> Option<Vec<Pixel>> {
        let Self {
            start,
            step_a,
            step_b,
            det,
            fa,
            fb,
            ..
        } = *self;
        let corners = [
            start + step_a * fa + step_b * fb,
            start + step_a * fa - step_b * fb,
            start - step_a * fa + step_b * fb,
            start - step_a * fa - step_b * fb,
        ];
        let (w, h) = (img.width_px as i64, img.height_px as i64);
        let x_lo = corners
            .iter()
            .map(|c| c.x)
            .fold(f64::INFINITY, f64::min)
            .ceil() as i64;
        let x_hi = corners
            .iter()
            .map(|c| c.x)
            .fold(f64::NEG_INFINITY, f64::max)
            .floor() as i64;
        let y_lo = corners
            .iter()
            .map(|c| c.y)
            .fold(f64::INFINITY, f64::min)
            .ceil() as i64;
        let y_hi = corners
            .iter()
            .map(|c| c.y)
            .fold(f64::NEG_INFINITY, f64::max)
            .floor() as i64;
        // The whole window must be inside the image: a window cut by the border loses the
        // symmetry that keeps the fit unbiased.
        if x_lo < 0 || y_lo < 0 || x_hi >= w || y_hi >= h {
            return None;
        }
        let mut pixels =
            Vec::with_capacity(((x_hi - x_lo + 1) * (y_hi - y_lo + 1)).max(0) as usize);
        for y in y_lo..=y_hi {
            for x in x_lo..=x_hi {
                let p = DVec2::new(x as f64, y as f64);
                let d = p - start;
                // Grid coordinates by Cramer's rule.
                let u = d.perp_dot(step_b) / det;
                let v = step_a.perp_dot(d) / det;
                let r = (u.abs() / fa).max(v.abs() / fb);
                if r >= 1.0 {
                    continue;
                }
                // Flat to 0.6 of the window, then a cosine taper to 0 at its edge.
                let weight = if r <= 0.6 {
                    1.0
                } else {
                    0.5 * (1.0 + (std::f64::consts::PI * (r - 0.6) / 0.4).cos())
                };
                let value = f64::from(img.values[(y * w + x) as usize]);
                if !value.is_finite() {
                    return None;
                }
                pixels.push(Pixel { p, value, weight });
            }
        }
        if pixels.len() < 3 * NP {
            return None;
        }
        Some(pixels)
    }

    /// The range the edge width `s` is kept in (px): 0.15 to half the corner spacing.
    fn edge_width_bounds(&self) -> (f64, f64) {
        (0.15, 0.5 * self.neighbour_px.max(1.0))
    }

    /// The starting parameters: the corner at `start`, the edges along the steps, edge width
    /// `s0` and the linear parameters fitted to `pixels`; `None` when that fit is singular.
    fn initial_params(&self, s0: f64, pixels: &[Pixel]) -> Option<Vec9> {
        let start = self.start;
        // Normals of the two edges: perpendicular to the edge directions.
        let na = self.step_a.perp().normalize_or_zero();
        let nb = self.step_b.perp().normalize_or_zero();
        let mut params = Vec9::zeros();
        params[0] = start.x;
        params[1] = start.y;
        params[2] = na.y.atan2(na.x);
        params[3] = nb.y.atan2(nb.x);
        params[4] = s0.ln();
        // Linear parameters (m, c, gₓ, g_y) by weighted least squares for the starting geometry.
        let mut ata = SMatrix::<f64, 4, 4>::zeros();
        let mut atb = SVector::<f64, 4>::zeros();
        let pre = Pre::new(&params);
        for px in pixels {
            let (_, g) = eval_pixel(&params, &pre, start, px.p, subsamples(params[4].exp()));
            let row = SVector::<f64, 4>::new(g[5], g[6], g[7], g[8]);
            ata += px.weight * row * row.transpose();
            atb += px.weight * px.value * row;
        }
        let lin = ata.cholesky()?.solve(&atb);
        params[5] = lin[0];
        params[6] = lin[1];
        params[7] = lin[2];
        params[8] = lin[3];
        Some(params)
    }

    /// The fit as a [`SaddleFit`] when plausible (module docs): the corner stayed within a
    /// third of the radius, and the contrast stands out of the residual.
    fn accept(&self, end: &LmEnd, pixels: &[Pixel]) -> Option<SaddleFit> {
        let params = end.params;
        let corner = DVec2::new(params[0], params[1]);
        let weight_sum: f64 = pixels.iter().map(|p| p.weight).sum();
        let residual_rms = (end.cost / weight_sum.max(1e-12)).sqrt();
        let s = params[4].exp();
        let contrast = params[6];
        let plausible = corner.is_finite()
            && (corner - self.start).length() <= self.radius / 3.0
            // (a noise-free flat window fits c ≈ 1e-17 with zero residual: contrast is also
            // measured against the window's mean level)
            && contrast.abs() > 4.0 * residual_rms.max(1e-9 * params[5].abs().max(1.0))
            && s.is_finite();
        plausible.then_some(SaddleFit {
            corner_px: corner,
            edge_width_px: s,
            contrast,
            residual_rms,
            iterations: end.iterations,
        })
    }
}

/// The least-squares problem of one window: its pixels about the window centre, the edge
/// width free or held, and the range it is kept in.
struct Problem<'a> {
    centre: DVec2,
    pixels: &'a [Pixel],
    fit_width: bool,
    /// `(s_min, s_max)`, px.
    s_bounds: (f64, f64),
}

/// The Levenberg–Marquardt iterate: parameters, their cost and the damping.
struct LmState {
    params: Vec9,
    cost: f64,
    lambda: f64,
}

/// Where the Levenberg–Marquardt iteration stopped.
struct LmEnd {
    params: Vec9,
    /// Weighted sum of squared residuals at `params`.
    cost: f64,
    iterations: usize,
    converged: bool,
}

impl Problem<'_> {
    /// Levenberg–Marquardt from `params` for at most `max_iterations`: converged when the
    /// corner stops moving or no damping lowers the cost.
    fn solve(&self, params: Vec9, max_iterations: usize) -> LmEnd {
        let mut state = LmState {
            params,
            cost: cost(&params, self.centre, self.pixels),
            lambda: 1e-3,
        };
        let mut converged = false;
        let mut iterations = 0;
        for it in 0..max_iterations {
            iterations = it + 1;
            let (jtj, jtr) = self.normal_equations(&state.params);
            match self.damped_step(&jtj, &jtr, &mut state) {
                // Converged when the corner (the only parameter we need) stops moving: a step
                // under 1e-4 px (1e-5 cost 11 % more detection time on the 70-pair synthetic
                // bench and changed no RMS beyond 1e-3 px).
                Some(moved) => converged = moved < 1e-4,
                // No decrease at any damping: at the minimum to machine precision.
                None => converged = true,
            }
            if converged {
                break;
            }
        }
        LmEnd {
            params: state.params,
            cost: state.cost,
            iterations,
            converged,
        }
    }

    /// `JᵀJ` and `Jᵀr` of the weighted residuals at `params` (the edge width's column zeroed
    /// and its diagonal 1 when it is held).
    fn normal_equations(&self, params: &Vec9) -> (Mat9, Vec9) {
        let mut jtj = Mat9::zeros();
        let mut jtr = Vec9::zeros();
        let n = subsamples(params[4].exp());
        let pre = Pre::new(params);
        for px in self.pixels {
            let (v, mut g) = eval_pixel(params, &pre, self.centre, px.p, n);
            if !self.fit_width {
                g[4] = 0.0;
            }
            // Upper triangle only (JᵀJ is symmetric; mirrored below): 45 products, not 81.
            for a in 0..NP {
                let wa = px.weight * g[a];
                for b in a..NP {
                    jtj[(a, b)] += wa * g[b];
                }
            }
            jtr += px.weight * (v - px.value) * g;
        }
        for a in 0..NP {
            for b in 0..a {
                jtj[(a, b)] = jtj[(b, a)];
            }
        }
        if !self.fit_width {
            // Fixed edge width: a unit diagonal keeps the system regular, the step stays 0.
            jtj[(4, 4)] = 1.0;
        }
        (jtj, jtr)
    }

    /// Tries up to ten dampings, growing tenfold from `state.lambda`; takes the first step
    /// that does not raise the cost (relaxing the damping) and returns how far it moved the
    /// corner (px). `None` when none does.
    fn damped_step(&self, jtj: &Mat9, jtr: &Vec9, state: &mut LmState) -> Option<f64> {
        let (s_min, s_max) = self.s_bounds;
        for _ in 0..10 {
            let mut a = *jtj;
            for k in 0..NP {
                a[(k, k)] += state.lambda * jtj[(k, k)].max(1e-12);
            }
            let Some(chol) = a.cholesky() else {
                state.lambda *= 10.0;
                continue;
            };
            let step = -chol.solve(jtr);
            let mut trial = state.params + step;
            // Keep the edge width within (0.1 px, half the spacing): beyond the upper end the
            // model degenerates to a quadratic saddle whose c and s trade off without bound
            // (the corner stays well defined, the iteration would drift).
            trial[4] = trial[4].clamp(s_min.ln(), s_max.ln());
            let c = cost(&trial, self.centre, self.pixels);
            if c.is_finite() && c <= state.cost {
                state.params = trial;
                state.cost = c;
                state.lambda = (state.lambda * 0.3).max(1e-9);
                return Some(DVec2::new(step[0], step[1]).length());
            }
            state.lambda *= 10.0;
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Renders a 4×4-supersampled checker corner at `corner` with edges along `u` and `v`,
    /// Gaussian noise of `noise` (contrast 100).
    fn render(w: usize, h: usize, corner: DVec2, u: DVec2, v: DVec2, noise: f64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let n = Normal::new(0.0, noise).unwrap_or_else(|e| panic!("{e}"));
        let (nu, nv) = (u.perp(), v.perp());
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let p = DVec2::new(
                            x as f64 - 0.375 + 0.25 * f64::from(sx),
                            y as f64 - 0.375 + 0.25 * f64::from(sy),
                        ) - corner;
                        let s = nu.dot(p).signum() * nv.dot(p).signum();
                        acc += 50.0 + 50.0 * s;
                    }
                }
                out[y * w + x] = (acc / 16.0 + n.sample(&mut rng)) as f32;
            }
        }
        out
    }

    #[test]
    fn recovers_a_sheared_corner_on_a_small_square() {
        let truth = DVec2::new(10.37, 9.71);
        let u = DVec2::new(1.0, 0.25);
        let v = DVec2::new(-0.15, 1.0);
        let values = render(21, 20, truth, u, v, 0.0);
        let img = FloatImage {
            width_px: 21,
            height_px: 20,
            values: &values,
        };
        let start = truth + DVec2::new(0.4, -0.3);
        // As the front end does: estimate the edge width, then fit with it held fixed.
        let width = fit_saddle(
            img,
            start,
            u * 6.0,
            v * 6.0,
            EdgeWidth::Estimate {
                guess_px: 0.5,
                max_iterations: 15,
            },
        )
        .map_or(0.5, |f| f.edge_width_px);
        let fit = fit_saddle(img, start, u * 6.0, v * 6.0, EdgeWidth::Fixed(width))
            .unwrap_or_else(|| panic!("fit rejected (edge width {width})"));
        let err = (fit.corner_px - truth).length();
        assert!(
            err < 0.02,
            "corner {:?} vs truth {truth:?}: error {err:.4} px, expected < 0.02 px",
            fit.corner_px
        );
    }

    #[test]
    fn fast_tanh_matches_libm() {
        for i in -4000..=4000 {
            let x = f64::from(i) * 0.01;
            let err = (tanh(x) - x.tanh()).abs();
            // Beyond |x| = 10 it returns ±1 (1 − tanh 10 = 4.1e-9).
            let bound = if x.abs() > 10.0 { 4.2e-9 } else { 1e-15 };
            assert!(
                err < bound,
                "tanh({x}) = {} vs libm {}: error {err:e}",
                tanh(x),
                x.tanh()
            );
        }
        assert_eq!(tanh(800.0), 1.0, "saturates without overflow");
        assert_eq!(tanh(-800.0), -1.0, "saturates without overflow");
    }

    #[test]
    fn value_path_matches_the_gradient_path() {
        let params =
            Vec9::from_column_slice(&[3.2, -1.1, 0.3, 1.9, (0.15f64).ln(), 40.0, 25.0, 0.5, -0.2]);
        let pre = Pre::new(&params);
        let centre = DVec2::new(2.0, -1.0);
        for y in -6..=6 {
            for x in -6..=6 {
                let p = DVec2::new(f64::from(x), f64::from(y));
                let (v, _) = eval_pixel(&params, &pre, centre, p, 8);
                let w = value_pixel(&params, &pre, centre, p, 8);
                assert!(
                    (v - w).abs() < 1e-12,
                    "pixel {p:?}: gradient path {v}, value path {w}"
                );
            }
        }
    }

    #[test]
    fn rejects_a_flat_window() {
        let values = vec![7f32; 20 * 20];
        let img = FloatImage {
            width_px: 20,
            height_px: 20,
            values: &values,
        };
        assert!(
            fit_saddle(
                img,
                DVec2::new(10.0, 10.0),
                DVec2::X * 6.0,
                DVec2::Y * 6.0,
                EdgeWidth::Fixed(0.5)
            )
            .is_none(),
            "a window without a corner must be rejected"
        );
    }
}
