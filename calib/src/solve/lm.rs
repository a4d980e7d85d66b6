//! Joint Levenberg–Marquardt over both cameras' intrinsics (fx, fy, cx, cy, k1, k2, p1, p2,
//! k3), the extrinsic `rgb_from_thermal`, and every board pose.
//!
//! * **Views.** A pair's board pose is `thermal_from_board` and its RGB corners are predicted
//!   through `rgb_from_thermal ∘ thermal_from_board`; a view seen by one camera only carries its
//!   own `cam_from_board`. So the extrinsic is constrained by pairs alone and unpaired views
//!   still constrain their camera's intrinsics.
//! * **Parameterisation.** Intrinsics additively; rigid transforms by a left-multiplied
//!   rotation increment `exp([δω]×)·R` and an additive translation.
//! * **Jacobian.** Central differences per parameter block (each residual touches at most
//!   9 + 6 + 6 parameters); block-sparse normal equations solved through the Schur complement
//!   onto the ≤ 24 global parameters ([`crate::solve::schur`]: linear in the number of views),
//!   Marquardt damping `(H + λ·diag H) δ = −g`.
//! * **Robust loss.** Huber on the corner's residual length with threshold `huber_px`
//!   (IRLS weights); after convergence corners with |r| > max(k·σ of their camera, 0.1 px)
//!   are rejected and
//!   the problem re-solved. Rejected corners are returned.
//! * **Weights.** Each camera's residuals are weighted by 1/σ_k², σ_k its residual σ from the
//!   previous solve (1 px before the first); solves repeat until no corner is rejected and the
//!   weights are stable to 10 % (at most 6 solves). So a noisy 160×120 thermal core does not
//!   pull the board poses that a 720p RGB camera pins far better.
//! * **Uncertainty.** Σ = s²·H⁻¹ at the solution (its global block, `s²·S⁻¹` of the Schur
//!   complement) (H = JᵀWJ with the weights above),
//!   s² = Σ wᵢ|rᵢ|² / (2·N − P). A camera whose residual σ is below `sigma_floor_px`
//!   (0.02 px per axis by default) is counted at the floor instead (weight capped at
//!   1/floor², s² ≥ 1): with the saddle-fit corners residuals reach 0.005 px per axis, a level
//!   at which systematic localisation errors (lens curvature of the edges inside the fit
//!   window, optics and rendering asymmetries) are absorbed into the board poses and no longer
//!   show in the residuals; on the synthetic Lepton set the extrinsic's z translation came out
//!   8.5 σ off with σ from the residuals alone (0.18 % of the baseline, a real error of
//!   0.12 mm). Directions the
//!   data do not constrain (eigenvalues below 1e-12 of the largest, in a pose's block or in the
//!   Schur complement) are given the floor eigenvalue, so their σ comes out huge but finite,
//!   never NaN.

use std::time::Instant;

use glam::{DQuat, DVec2, DVec3};
use nalgebra::DVector;

use crate::solve::schur::{BlockNormal, ResidualJacobian};
use serde::Serialize;

use crate::detect::board::Camera;
use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::model::geometry::Rigid3;

/// Frame of a view's board pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseFrame {
    /// `thermal_from_board` (pairs and thermal-only views).
    Thermal,
    /// `rgb_from_board` (RGB-only views).
    Rgb,
}

/// One camera's corners of one view.
#[derive(Debug, Clone)]
pub struct Observation {
    pub camera: Camera,
    pub view: usize,
    pub corners_px: Vec<DVec2>,
    /// Index into [`Problem::object_points_m`] of each corner (a partial board sees a subset).
    pub corner_ids: Vec<usize>,
    /// False for corners rejected as outliers.
    pub inlier: Vec<bool>,
}

impl Observation {
    /// All of a whole board's corners, every one an inlier.
    pub fn whole(camera: Camera, view: usize, corners_px: Vec<DVec2>) -> Self {
        let n = corners_px.len();
        Self::subset(camera, view, corners_px, (0..n).collect())
    }

    /// Corners `corner_ids` of the board, every one an inlier.
    pub fn subset(
        camera: Camera,
        view: usize,
        corners_px: Vec<DVec2>,
        corner_ids: Vec<usize>,
    ) -> Self {
        let n = corners_px.len();
        Self {
            camera,
            view,
            corners_px,
            corner_ids,
            inlier: vec![true; n],
        }
    }

    /// Each observed corner with its board point, in corner order (an id outside `object`
    /// gives a NaN point: its residual is not finite and the corner is rejected).
    fn points<'a>(&'a self, object: &'a [DVec3]) -> impl Iterator<Item = (&'a DVec2, DVec3)> + 'a {
        self.corners_px
            .iter()
            .zip(&self.corner_ids)
            .map(|(p, &i)| (p, object.get(i).copied().unwrap_or(DVec3::NAN)))
    }
}

/// The problem state (also the solution).
#[derive(Debug, Clone)]
pub struct Problem {
    pub object_points_m: Vec<DVec3>,
    /// `[thermal, rgb]`; `None` for a camera not in the data.
    pub cameras: [Option<CameraModel>; 2],
    pub rgb_from_thermal: Option<Rigid3>,
    pub poses: Vec<(PoseFrame, Rigid3)>,
    pub observations: Vec<Observation>,
}

/// Solver settings.
#[derive(Debug, Clone, Copy)]
pub struct SolveOptions {
    pub huber_px: f64,
    pub reject_sigma: f64,
    /// Residuals below this are never rejected (px): with near-perfect data k·σ would
    /// otherwise cut into rounding noise.
    pub reject_floor_px: f64,
    /// Smallest per-axis corner noise the uncertainties assume (px); see the module docs.
    pub sigma_floor_px: f64,
    pub max_iterations: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            huber_px: 1.0,
            reject_sigma: 4.0,
            reject_floor_px: 0.1,
            sigma_floor_px: 0.02,
            max_iterations: 100,
        }
    }
}

/// One solver iteration, for the error-vs-time report.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct IterationLog {
    pub iteration: usize,
    pub wall_s: f64,
    /// RMS over inlier corners (px, per corner length / √2 summed as OpenCV does: sqrt(Σ|r|²/N)).
    pub rms_px: f64,
    pub lambda: f64,
}

/// A corner removed by the k·σ test.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RejectedCorner {
    pub camera: Camera,
    pub view: usize,
    /// The board's corner index (row-major).
    pub corner: usize,
    pub residual_px: f64,
}

/// One σ per solved quantity (same units as the quantity; rotation in degrees).
#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct IntrinsicSigma {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

/// σ of the extrinsic: rotation increments (deg, about x, y, z) and translation (m).
#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct ExtrinsicSigma {
    pub rotation_deg: [f64; 3],
    pub translation_m: [f64; 3],
}

/// What the solver returns besides the updated [`Problem`].
#[derive(Debug, Clone, Serialize)]
pub struct SolveReport {
    pub iterations: Vec<IterationLog>,
    pub rejected: Vec<RejectedCorner>,
    pub intrinsic_sigma: [Option<IntrinsicSigma>; 2],
    pub extrinsic_sigma: Option<ExtrinsicSigma>,
    /// Residual standard deviation s (px per axis).
    pub residual_sigma_px: f64,
    /// Parameter directions with (near-)zero information, by name.
    pub unconstrained: Vec<String>,
    pub converged: bool,
    pub wall_s: f64,
}

fn intr_to_array(c: &CameraModel) -> [f64; 9] {
    let i = c.intrinsics;
    let d = c.distortion;
    [i.fx, i.fy, i.cx, i.cy, d.k1, d.k2, d.p1, d.p2, d.k3]
}

fn array_to_cam(base: &CameraModel, a: &[f64; 9]) -> CameraModel {
    CameraModel {
        width_px: base.width_px,
        height_px: base.height_px,
        intrinsics: Intrinsics {
            fx: a[0],
            fy: a[1],
            cx: a[2],
            cy: a[3],
        },
        distortion: BrownConrady {
            k1: a[4],
            k2: a[5],
            p1: a[6],
            p2: a[7],
            k3: a[8],
        },
    }
}

const INTRINSIC_NAMES: [&str; 9] = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];

/// Applies a 6-vector increment (rotation vector, translation) to a rigid transform.
pub fn perturb(t: &Rigid3, d: &[f64]) -> Rigid3 {
    let w = DVec3::new(d[0], d[1], d[2]);
    Rigid3 {
        rotation: (DQuat::from_scaled_axis(w) * t.rotation).normalize(),
        translation_m: t.translation_m + DVec3::new(d[3], d[4], d[5]),
    }
}

/// Parameter layout.
struct Layout {
    intr: [Option<usize>; 2],
    ext: Option<usize>,
    pose0: usize,
    n: usize,
}

impl Layout {
    fn new(p: &Problem) -> Self {
        let mut n = 0;
        let mut intr = [None, None];
        for (k, c) in p.cameras.iter().enumerate() {
            if c.is_some() {
                intr[k] = Some(n);
                n += 9;
            }
        }
        let ext = p.rgb_from_thermal.map(|_| {
            n += 6;
            n - 6
        });
        let pose0 = n;
        n += 6 * p.poses.len();
        Self {
            intr,
            ext,
            pose0,
            n,
        }
    }
}

/// State as flat parts, for projection with perturbations.
#[derive(Clone)]
struct State {
    intr: [[f64; 9]; 2],
    base: [CameraModel; 2],
    ext: Rigid3,
    poses: Vec<Rigid3>,
}

impl State {
    fn from_problem(p: &Problem) -> Self {
        let fallback = p
            .cameras
            .iter()
            .flatten()
            .next()
            .copied()
            .unwrap_or(CameraModel {
                width_px: 1,
                height_px: 1,
                intrinsics: Intrinsics {
                    fx: 1.0,
                    fy: 1.0,
                    cx: 0.0,
                    cy: 0.0,
                },
                distortion: BrownConrady::default(),
            });
        let base = [
            p.cameras[0].unwrap_or(fallback),
            p.cameras[1].unwrap_or(fallback),
        ];
        Self {
            intr: [intr_to_array(&base[0]), intr_to_array(&base[1])],
            base,
            ext: p.rgb_from_thermal.unwrap_or(Rigid3::IDENTITY),
            poses: p.poses.iter().map(|(_, t)| *t).collect(),
        }
    }

    fn apply(&self, layout: &Layout, delta: &DVector<f64>) -> Self {
        let mut s = self.clone();
        for k in 0..2 {
            if let Some(o) = layout.intr[k] {
                for j in 0..9 {
                    s.intr[k][j] += delta[o + j];
                }
            }
        }
        if let Some(o) = layout.ext {
            let d: Vec<f64> = (0..6).map(|j| delta[o + j]).collect();
            s.ext = perturb(&self.ext, &d);
        }
        for (v, pose) in s.poses.iter_mut().enumerate() {
            let o = layout.pose0 + 6 * v;
            let d: Vec<f64> = (0..6).map(|j| delta[o + j]).collect();
            *pose = perturb(&self.poses[v], &d);
        }
        s
    }

    fn write_back(&self, p: &mut Problem) {
        for k in 0..2 {
            if let Some(c) = p.cameras[k].as_mut() {
                *c = array_to_cam(c, &self.intr[k]);
            }
        }
        if p.rgb_from_thermal.is_some() {
            p.rgb_from_thermal = Some(self.ext);
        }
        for (v, (_, t)) in p.poses.iter_mut().enumerate() {
            *t = self.poses[v];
        }
    }
}

/// Projection of one board point for an observation, with explicit parts (for differencing).
fn project(
    intr: &[f64; 9],
    base: &CameraModel,
    frame: PoseFrame,
    camera: Camera,
    ext: &Rigid3,
    pose: &Rigid3,
    point: DVec3,
) -> DVec2 {
    let cam = array_to_cam(base, intr);
    let cam_from_board = match (camera, frame) {
        (Camera::Rgb, PoseFrame::Thermal) => ext.compose(pose),
        _ => *pose,
    };
    let p = cam_from_board.transform_point(point);
    // Points behind the camera get a large, finite residual instead of NaN.
    cam.project(p).unwrap_or(DVec2::splat(1e6))
}

/// Per-corner residuals (predicted − observed) in px.
pub fn residuals(p: &Problem) -> Vec<Vec<DVec2>> {
    let s = State::from_problem(p);
    p.observations
        .iter()
        .map(|o| {
            let (frame, _) = p.poses[o.view];
            let k = o.camera.index();
            o.points(&p.object_points_m)
                .map(|(obs, x)| {
                    project(
                        &s.intr[k],
                        &s.base[k],
                        frame,
                        o.camera,
                        &s.ext,
                        &s.poses[o.view],
                        x,
                    ) - *obs
                })
                .collect()
        })
        .collect()
}

fn cost_and_rms(p: &Problem, s: &State, huber: f64, cam_w: [f64; 2]) -> (f64, f64, usize) {
    let mut cost = 0.0;
    let mut ss = 0.0;
    let mut n = 0usize;
    for o in &p.observations {
        let (frame, _) = p.poses[o.view];
        let k = o.camera.index();
        for (j, (obs, x)) in o.points(&p.object_points_m).enumerate() {
            if !o.inlier[j] {
                continue;
            }
            let r = project(
                &s.intr[k],
                &s.base[k],
                frame,
                o.camera,
                &s.ext,
                &s.poses[o.view],
                x,
            ) - *obs;
            let e2 = r.length_squared();
            ss += e2;
            n += 1;
            cost += cam_w[k]
                * if e2 <= huber * huber {
                    e2
                } else {
                    2.0 * huber * e2.sqrt() - huber * huber
                };
        }
    }
    (cost, (ss / n.max(1) as f64).sqrt(), n)
}

/// Central differences of `f` over a rigid perturbation's six coordinates ([`perturb`]:
/// rotation steps 1e-6 rad, translation steps 1e-7).
fn rigid_jacobian(f: impl Fn(&[f64; 6]) -> DVec2) -> [DVec2; 6] {
    let mut jac = [DVec2::ZERO; 6];
    let mut d = [0.0; 6];
    for q in 0..6 {
        let step = if q < 3 { 1e-6 } else { 1e-7 };
        d[q] = step;
        let plus = f(&d);
        d[q] = -step;
        let minus = f(&d);
        d[q] = 0.0;
        jac[q] = (plus - minus) / (2.0 * step);
    }
    jac
}

/// Builds H = JᵀWJ and g = JᵀWr in blocks; returns also Σ w|r|² and N.
fn normal_equations(
    p: &Problem,
    s: &State,
    layout: &Layout,
    huber: f64,
    cam_w: [f64; 2],
) -> (BlockNormal, f64, usize) {
    let mut normal = BlockNormal::zeros(layout.pose0, p.poses.len());
    let mut wss = 0.0;
    let mut count = 0usize;
    let mut global: Vec<(usize, DVec2)> = Vec::with_capacity(15);
    for o in &p.observations {
        let (frame, _) = p.poses[o.view];
        let k = o.camera.index();
        let uses_ext = o.camera == Camera::Rgb && frame == PoseFrame::Thermal;
        for (j, (obs, x)) in o.points(&p.object_points_m).enumerate() {
            if !o.inlier[j] {
                continue;
            }
            let pose = &s.poses[o.view];
            let r = project(&s.intr[k], &s.base[k], frame, o.camera, &s.ext, pose, x) - *obs;
            let e = r.length();
            let w = cam_w[k] * if e <= huber { 1.0 } else { huber / e };
            wss += w * e * e;
            count += 1;
            global.clear();
            if let Some(off) = layout.intr[k] {
                for q in 0..9 {
                    let step = if q < 2 {
                        1e-5 * s.intr[k][q].abs().max(1.0)
                    } else if q < 4 {
                        1e-4
                    } else {
                        1e-6
                    };
                    let mut a = s.intr[k];
                    a[q] += step;
                    let plus = project(&a, &s.base[k], frame, o.camera, &s.ext, pose, x);
                    a[q] -= 2.0 * step;
                    let minus = project(&a, &s.base[k], frame, o.camera, &s.ext, pose, x);
                    global.push((off + q, (plus - minus) / (2.0 * step)));
                }
            }
            if uses_ext && let Some(off) = layout.ext {
                let jac = rigid_jacobian(|d| {
                    let ext = perturb(&s.ext, d);
                    project(&s.intr[k], &s.base[k], frame, o.camera, &ext, pose, x)
                });
                global.extend(jac.iter().enumerate().map(|(q, &v)| (off + q, v)));
            }
            let pose_jac = rigid_jacobian(|d| {
                let moved = perturb(pose, d);
                project(&s.intr[k], &s.base[k], frame, o.camera, &s.ext, &moved, x)
            });
            normal.add(
                &ResidualJacobian {
                    global: &global,
                    pose: o.view,
                    pose_jac: &pose_jac,
                },
                r,
                w,
            );
        }
    }
    (normal, wss, count)
}

fn lm(
    p: &mut Problem,
    opts: &SolveOptions,
    cam_w: [f64; 2],
    log: &mut Vec<IterationLog>,
    start: Instant,
) -> bool {
    let layout = Layout::new(p);
    let mut s = State::from_problem(p);
    let (mut cost, rms, _) = cost_and_rms(p, &s, opts.huber_px, cam_w);
    let mut lambda = 1e-3;
    let iter0 = log.len();
    log.push(IterationLog {
        iteration: iter0,
        wall_s: start.elapsed().as_secs_f64(),
        rms_px: rms,
        lambda,
    });
    let mut converged = false;
    for _ in 0..opts.max_iterations {
        let (normal, _, _) = normal_equations(p, &s, &layout, opts.huber_px, cam_w);
        let mut accepted = false;
        for _ in 0..12 {
            let Some(delta) = normal.damped_step(lambda) else {
                lambda *= 10.0;
                continue;
            };
            if !delta.iter().all(|v| v.is_finite()) {
                lambda *= 10.0;
                continue;
            }
            let candidate = s.apply(&layout, &delta);
            let (c, rms, _) = cost_and_rms(p, &candidate, opts.huber_px, cam_w);
            if c.is_finite() && c < cost {
                let rel = (cost - c) / cost.max(1e-300);
                s = candidate;
                cost = c;
                lambda = (lambda / 3.0).max(1e-12);
                accepted = true;
                log.push(IterationLog {
                    iteration: log.len(),
                    wall_s: start.elapsed().as_secs_f64(),
                    rms_px: rms,
                    lambda,
                });
                if rel < 1e-10 || delta.amax() < 1e-12 {
                    converged = true;
                }
                break;
            }
            lambda *= 4.0;
        }
        if !accepted {
            // No decrease possible at any damping: at a minimum (to numerical precision).
            converged = true;
        }
        if converged {
            break;
        }
    }
    s.write_back(p);
    converged
}

/// Pooled residual σ in pixels (per axis, Huber-weighted, without the per-camera weights).
fn residual_sigma_px(p: &Problem, huber: f64, dof: usize) -> f64 {
    let res = residuals(p);
    let mut ss = 0.0;
    for (o, r) in p.observations.iter().zip(&res) {
        for (j, e) in r.iter().enumerate() {
            if o.inlier[j] {
                let e = e.length();
                ss += if e <= huber { e * e } else { huber * e };
            }
        }
    }
    (ss / dof.max(1) as f64).sqrt()
}

/// Solves the joint problem in place.
pub fn solve(p: &mut Problem, opts: &SolveOptions) -> SolveReport {
    let start = Instant::now();
    let mut log = Vec::new();
    let mut rejected = Vec::new();
    let mut converged = false;
    // Per-camera weights 1/σ_k² (σ_k: that camera's residual σ from the previous round; 1 px
    // before the first). A 160×120 thermal core and a 720p RGB camera differ several-fold in
    // corner noise; equal weights would let the noisier camera pull the shared board poses.
    let mut cam_w = [1.0f64; 2];
    for _round in 0..6 {
        converged = lm(p, opts, cam_w, &mut log, start);
        // k·σ rejection per camera.
        let res = residuals(p);
        let mut sigma = [0.0f64; 2];
        let mut counts = [0usize; 2];
        for (o, r) in p.observations.iter().zip(&res) {
            for (j, e) in r.iter().enumerate() {
                if o.inlier[j] {
                    sigma[o.camera.index()] += e.length_squared();
                    counts[o.camera.index()] += 1;
                }
            }
        }
        for k in 0..2 {
            sigma[k] = (sigma[k] / (2.0 * counts[k].max(1) as f64)).sqrt();
        }
        let mut reweighted = false;
        for k in 0..2 {
            if counts[k] > 0 && sigma[k].is_finite() && sigma[k] > 0.0 {
                // Floor at 0.01 px so a perfect synthetic camera cannot get an infinite weight.
                let w = 1.0 / sigma[k].max(0.01).powi(2);
                if (w / cam_w[k] - 1.0).abs() > 0.1 {
                    reweighted = true;
                }
                cam_w[k] = w;
            }
        }
        let mut newly = 0usize;
        for (o, r) in p.observations.iter_mut().zip(&res) {
            let limit = (opts.reject_sigma * sigma[o.camera.index()]).max(opts.reject_floor_px);
            for (j, e) in r.iter().enumerate() {
                let len = e.length();
                if o.inlier[j] && (len > limit || !len.is_finite()) {
                    o.inlier[j] = false;
                    newly += 1;
                    rejected.push(RejectedCorner {
                        camera: o.camera,
                        view: o.view,
                        corner: o.corner_ids.get(j).copied().unwrap_or(j),
                        residual_px: len,
                    });
                }
            }
        }
        if newly == 0 && !reweighted {
            break;
        }
    }
    // Covariance.
    let layout = Layout::new(p);
    let s = State::from_problem(p);
    // Corner noise below `sigma_floor_px` is not believed (module docs): such a camera's
    // weight is capped at 1/floor² and the scale s² kept ≥ 1, so its corners count as having
    // the floor's noise. Above the floor, s² = Σ wᵢ|rᵢ|²/(2N − P) ≥ 1 already (the weights
    // come from the same residuals over 2N) and nothing changes.
    let floor_w = 1.0 / opts.sigma_floor_px.max(1e-6).powi(2);
    let cov_w = cam_w.map(|w| w.min(floor_w));
    let (normal, wss, count) = normal_equations(p, &s, &layout, opts.huber_px, cov_w);
    let dof = (2 * count).saturating_sub(layout.n).max(1);
    let s2 = (wss / dof as f64).max(1.0);
    let mut null = Vec::new();
    // Global parameters only: the board poses' σ are not reported.
    let cov = normal.global_covariance(s2, &mut null);
    let unconstrained: Vec<String> = null.iter().map(|&i| param_name(&layout, i)).collect();
    let sd = |i: usize| {
        cov.as_ref()
            .map_or(f64::INFINITY, |c| c[(i, i)].max(0.0).sqrt())
    };
    let mut intrinsic_sigma = [None, None];
    for (slot, offset) in intrinsic_sigma.iter_mut().zip(layout.intr) {
        if let Some(o) = offset {
            *slot = Some(IntrinsicSigma {
                fx: sd(o),
                fy: sd(o + 1),
                cx: sd(o + 2),
                cy: sd(o + 3),
                k1: sd(o + 4),
                k2: sd(o + 5),
                p1: sd(o + 6),
                p2: sd(o + 7),
                k3: sd(o + 8),
            });
        }
    }
    let extrinsic_sigma = layout.ext.map(|o| ExtrinsicSigma {
        rotation_deg: [
            sd(o).to_degrees(),
            sd(o + 1).to_degrees(),
            sd(o + 2).to_degrees(),
        ],
        translation_m: [sd(o + 3), sd(o + 4), sd(o + 5)],
    });
    SolveReport {
        iterations: log,
        rejected,
        intrinsic_sigma,
        extrinsic_sigma,
        residual_sigma_px: residual_sigma_px(p, opts.huber_px, dof),
        unconstrained,
        converged,
        wall_s: start.elapsed().as_secs_f64(),
    }
}

fn param_name(layout: &Layout, i: usize) -> String {
    for (k, cam) in Camera::BOTH.iter().enumerate() {
        if let Some(o) = layout.intr[k]
            && (o..o + 9).contains(&i)
        {
            return format!("{}.{}", cam.name(), INTRINSIC_NAMES[i - o]);
        }
    }
    if let Some(o) = layout.ext
        && (o..o + 6).contains(&i)
    {
        return format!("rgb_from_thermal[{}]", i - o);
    }
    format!(
        "pose[{}][{}]",
        (i - layout.pose0) / 6,
        (i - layout.pose0) % 6
    )
}
