//! Bundle adjustment of the planar method: every camera's centre and rotation, every 3-D point
//! and the wall's plane, refined together from the pixel observations, the cameras' GPS,
//! barometric altitude and gimbal attitude, and the points' coplanarity.
//!
//! Why: the planar registration (module docs of [`super`]) gives each shot a pose from its
//! gimbal attitude and its in-plane offset, and each matched patch a point on the assumed wall.
//! The gimbal is off by about a degree, GPS by decimetres to metres and the wall is not exactly
//! where it was assumed, so the reprojections start tens of pixels off. The joint refinement
//! makes them sub-pixel, while the priors hold the gauge (the similarity that images alone leave
//! free) near GPS, altitude and attitude.
//!
//! ## Unknowns
//! - Camera `c`: its centre `C` (3, world metres: east, north, up, updated additively) and a
//!   rotation correction `δ` (3, radians) right-multiplied onto the rotation:
//!   `R ← R·exp([δ]×)` (`R` is world_from_cam, camera axes x right, y down, z forward; `δ` is
//!   expressed in the camera's frame).
//! - Point `j`: `X` (3, world metres, additive).
//! - The plane `n·X = d`: the normal `n = normalize(n₀ + q₀·a + q₁·b)` with `n₀, a, b` the given
//!   orthonormal axes ([`PlaneInit`]: forward, right, down of a reference orientation; `q`
//!   starts at 0), and the distance `d`: 3 parameters `(q₀, q₁, d)`, never degenerate
//!   (`|n₀ + q₀·a + q₁·b| ≥ 1`), unlike three free components of a unit vector.
//!
//! ## Cost
//! `Σ ρ_H(|π(R_cᵀ(X_j − C_c)) − uv|)` over observations (pinhole `π`, no distortion: the images
//! are undistorted before; residuals in pixels, i.e. a pixel σ of 1 px)
//! `+ Σ ρ_GM(|n·X_j − d| / σ_plane)` over points
//! `+ Σ ((C_e − gps_e)² + (C_n − gps_n)²) / σ_gps² + (C_u − alt)² / σ_alt²` over cameras that
//! have them
//! `+ Σ |log(R₀ᵀR)|² / σ_rot²` over cameras (`R₀` the initial, gimbal, rotation).
//!
//! Both robust losses act on a normalised residual `e` and are minimised by iteratively
//! reweighted least squares: at each linearisation every robust residual gets the weight
//! `w = ∂ρ/∂(e²)`. Both losses are concave in `e²`, so the weighted quadratic is a majoriser of
//! `ρ` touching it at the current point and a step that lowers the model lowers the cost.
//! - Reprojections: Huber, `ρ_H(e) = e²` up to 2 px, `4e − 4` beyond, weight `min(1, 2/e)`
//!   (the script's `sqrt(2/e)` on residual and Jacobian): mismatched patches pull with a
//!   bounded force.
//! - Plane: Geman–McClure, `ρ_GM(e) = c²e²/(c² + e²)` with `c = 3` (σ units), weight
//!   `(c²/(c² + e²))²`: quadratic near the wall, redescending beyond. The script's Huber
//!   (beyond 2σ) let points on windows, eaves or balconies that really leave the wall keep
//!   pulling towards it with a constant force, which their few views resist only by bending
//!   the cameras: on the synthetic facade (tests) with 15 % of the points 0.3 m (6σ) off the
//!   wall it left 0.5–0.6° of rotation error (rms over the cameras) where Geman–McClure leaves
//!   0.15–0.2°, no more than with every point on the wall. Points start on (or near) the plane
//!   (the planar method seeds them there), so the non-convex loss starts in its quadratic
//!   part.
//!
//! A σ of `f64::INFINITY` drops that prior (or the plane term) entirely.
//!
//! ## Solve: Levenberg–Marquardt on the Schur complement
//! With the parameters ordered cameras (6 each), plane (3), points (3 each), the damped normal
//! equations `(H + λ·diag H) δ = −g` have the shape
//!
//! ```text
//!     ┌ U        W ┐     U: block diagonal over cameras (6 × 6: their reprojections and
//! H = │            │        priors) and the plane (3 × 3: the plane terms of all points)
//!     └ Wᵀ       V ┘     V: block diagonal over points (3 × 3: a point's reprojections and
//!                           its plane term); W: camera–point (6 × 3, one per observation)
//!                           and plane–point (3 × 3, one per point) couplings
//! ```
//!
//! Every plane term couples its point to the 3 plane parameters, so the plane belongs to the
//! reduced side with the cameras. Points are eliminated: `S = U − W V⁻¹ Wᵀ` (dense,
//! `6·cameras + 3` square: ≈ 550 for 90 cameras, Cholesky), `S δ_red = −g_red + W V⁻¹ g_pt`,
//! then each point's step from its own 3 × 3 block. A dense solve of all ≈ 3000 unknowns
//! would cost ~150× more per step. At a real folder's size (90 cameras, 900 points, 1800
//! observations) an iteration takes ≈ 16 ms optimised, 25–35 ms in the dev profile.
//!
//! Steps are accepted when they lower the robust cost (evaluated exactly, not through the
//! model); λ is divided by 10 on acceptance and multiplied by 10 on rejection. The loop stops
//! after `iterations` accepted steps, when a step lowers the cost by less than 1e-10 of it, or
//! when no λ up to 1e10 gives a lower cost (a minimum). The damping is Marquardt's (relative to
//! the diagonal) with a small floor (1e-6 · λ), so a camera or point without any information
//! (no observation, no prior) keeps a positive-definite block and simply does not move.
//!
//! ## Degenerate cases
//! A point behind a camera that observes it (depth ≤ 1 µm) at the start is an error
//! ([`BundleError::PointBehindCamera`], naming both). During the iterations a trial step that
//! would put any observed point behind its camera has infinite cost and is rejected (λ grows),
//! so the solution never contains one. Non-finite input, indices out of range, inconsistent
//! lengths, matrices that are not rotations and non-orthonormal plane axes are errors before
//! anything is solved.
//!
//! ## Expected accuracy
//! - Start: the robust losses make it forgiving (Huber is L1-like on large errors), but the
//!   linearisation must see the right basin: on the synthetic facade (cameras 3 m from the
//!   wall) centres 0.3 m, rotations 1°, points 0.1 m and the plane's normal 2° off (≈ 50 px
//!   reprojections) converge to the noise in under 10 iterations. Centres off by more than a
//!   fraction of the distance to the wall, or rotations by several degrees, may not.
//! - Result: a wall seen face-on is at one depth, so turning a camera about an axis in the
//!   wall's plane moves its image almost as translating it along the wall does; only the
//!   perspective across the image and points off the wall tell them apart, and with each point
//!   in 2–3 views (its in-plane position free) that separation is weak. A camera's rotation
//!   about the in-plane axes is then about as uncertain as its centre along the wall divided
//!   by the distance to the wall: 0.3° per camera with 2 cm centre priors on the synthetic
//!   facade (its covariance), more with metre-level GPS, where the gimbal prior (`σ_rot`)
//!   and more points per camera are what hold it. The reprojection error does not show this.
//! - Outliers: with a point in only two views, an outlier along the epipolar line is a point
//!   off the wall; beyond a few `σ_plane` the plane term lets go, the point moves and absorbs
//!   the outlier (no pull on the cameras, but no large residual to flag it either). An
//!   outlier in a point with three views keeps its residual.

use nalgebra::{DMatrix, DVector, Matrix2x3, Matrix3, SMatrix, SVector, Vector2, Vector3};

type Mat6 = SMatrix<f64, 6, 6>;
type Vec6 = SVector<f64, 6>;
type Mat6x3 = SMatrix<f64, 6, 3>;
type Mat2x6 = SMatrix<f64, 2, 6>;

/// Huber threshold of the reprojection residuals, pixels.
const HUBER_PX: f64 = 2.0;
/// Scale of the plane residuals' Geman–McClure loss, in units of `σ_plane`.
const PLANE_SCALE_SIGMAS: f64 = 3.0;
/// A point at or below this depth (metres, along the camera's z) is behind the camera.
const MIN_DEPTH_M: f64 = 1e-6;
/// The damping's floor on a diagonal entry: `H_ii + λ·max(H_ii, DAMP_FLOOR)`.
const DAMP_FLOOR: f64 = 1e-6;
/// The first λ (relative to the diagonal).
const LAMBDA_START: f64 = 1e-3;
/// λ never goes below this (rounding in `S` must stay covered by the damping).
const LAMBDA_MIN: f64 = 1e-9;
/// No step lowering the cost up to this λ: the current state is a minimum.
const LAMBDA_MAX: f64 = 1e10;
/// Converged when an accepted step lowers the cost by less than this fraction of it.
const REL_COST_TOL: f64 = 1e-10;
/// Tolerance of the rotation and plane-axes orthonormality checks.
const ORTHO_TOL: f64 = 1e-6;

/// One image measurement: camera `camera` sees point `point` at pixel `uv` (undistorted image,
/// pixel-centre origin as the intrinsics).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Index into [`BundleProblem::rotations`] / [`BundleProblem::centres`].
    pub camera: usize,
    /// Index into [`BundleProblem::points`].
    pub point: usize,
    /// Measured pixel `(u, v)`.
    pub uv: [f64; 2],
}

/// Standard deviations of the priors and of the plane term. `f64::INFINITY` drops that term.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sigmas {
    /// GPS, each of east and north, metres.
    pub gps_m: f64,
    /// Barometric altitude (the centre's up), metres.
    pub alt_m: f64,
    /// Each component of `log(R₀ᵀR)`, radians.
    pub rot_rad: f64,
    /// A point's signed distance from the plane, metres.
    pub plane_m: f64,
}

/// The initial plane `normal·X = distance` and the axes of its normal's parametrisation (module
/// docs): `normal`, `right`, `down` must be orthonormal (forward, right, down of a reference
/// orientation, e.g. the mean camera's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneInit {
    /// Unit normal `n₀` (the reference forward).
    pub normal: Vector3<f64>,
    /// First tilt axis `a`.
    pub right: Vector3<f64>,
    /// Second tilt axis `b`.
    pub down: Vector3<f64>,
    /// `d` in `n·X = d`, metres.
    pub distance: f64,
}

/// Everything the bundle adjustment needs: intrinsics, initial values, priors, observations.
/// The per-camera vectors (`rotations`, `centres`, `gps_en`, `altitude`) have one entry per
/// camera.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleProblem {
    /// Focal length, pixels.
    pub focal_px: f64,
    /// Principal point, pixels.
    pub cx: f64,
    /// Principal point, pixels.
    pub cy: f64,
    /// Initial world_from_cam rotations (camera x right, y down, z forward); also the
    /// rotation priors.
    pub rotations: Vec<Matrix3<f64>>,
    /// Initial camera centres (world: east, north, up, metres).
    pub centres: Vec<Vector3<f64>>,
    /// Prior on each centre's east and north (GPS), metres; `None`: no prior.
    pub gps_en: Vec<Option<[f64; 2]>>,
    /// Prior on each centre's up (barometric altitude), metres; `None`: no prior.
    pub altitude: Vec<Option<f64>>,
    /// Initial points (world metres).
    pub points: Vec<Vector3<f64>>,
    /// Pixel measurements of points by cameras.
    pub observations: Vec<Observation>,
    /// Initial plane and its parametrisation's axes.
    pub plane: PlaneInit,
    /// Prior and plane σs.
    pub sigmas: Sigmas,
    /// Maximum number of Levenberg–Marquardt iterations (accepted steps).
    pub iterations: usize,
}

/// The refined scene.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleSolution {
    /// Refined world_from_cam rotations, one per camera.
    pub rotations: Vec<Matrix3<f64>>,
    /// Refined camera centres, one per camera.
    pub centres: Vec<Vector3<f64>>,
    /// Refined points, one per input point.
    pub points: Vec<Vector3<f64>>,
    /// Refined unit plane normal.
    pub normal: Vector3<f64>,
    /// Refined plane distance: `normal·X = distance`.
    pub distance: f64,
    /// Per observation (input order): final, unweighted pixel error norm.
    pub reprojection_px: Vec<f64>,
    /// Accepted Levenberg–Marquardt steps.
    pub iterations: usize,
    /// Robust cost (module docs) at the start.
    pub initial_cost: f64,
    /// Robust cost at the solution.
    pub final_cost: f64,
}

/// Why a bundle problem was refused.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    /// A per-camera vector does not have one entry per camera.
    #[error("{what} has {got} entries, expected {expected} (one per camera)")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// An observation names a camera that does not exist.
    #[error("observation {observation} names camera {camera}, but there are {cameras} cameras")]
    CameraOutOfRange {
        observation: usize,
        camera: usize,
        cameras: usize,
    },
    /// An observation names a point that does not exist.
    #[error("observation {observation} names point {point}, but there are {points} points")]
    PointOutOfRange {
        observation: usize,
        point: usize,
        points: usize,
    },
    /// A NaN or infinity in the input.
    #[error("non-finite {what} (index {index})")]
    NonFinite { what: &'static str, index: usize },
    /// A rotation that is not orthonormal with determinant +1.
    #[error(
        "rotation of camera {camera} is not a rotation (|RᵀR − I| = {deviation:e}, det = {det})"
    )]
    NotARotation {
        camera: usize,
        deviation: f64,
        det: f64,
    },
    /// The plane's normal, right and down are not orthonormal.
    #[error("plane axes (normal, right, down) are not orthonormal (|AᵀA − I| = {deviation:e})")]
    PlaneAxes { deviation: f64 },
    /// A σ that is not positive (infinity is allowed: the term is dropped).
    #[error("sigma {name} must be positive (or infinite to drop the term), got {value}")]
    InvalidSigma { name: &'static str, value: f64 },
    /// A focal length that is not positive and finite.
    #[error("focal length must be positive and finite, got {focal_px} px")]
    InvalidFocal { focal_px: f64 },
    /// A point at or behind a camera that observes it, in the initial values.
    #[error(
        "point {point} is behind camera {camera} (depth {depth_m} m) in observation {observation} at the start"
    )]
    PointBehindCamera {
        observation: usize,
        camera: usize,
        point: usize,
        depth_m: f64,
    },
}

/// Refines cameras, points and plane (module docs). Errors only on invalid input; a problem that
/// cannot be improved returns its initial values.
pub fn solve(problem: &BundleProblem) -> Result<BundleSolution, BundleError> {
    validate(problem)?;
    let ctx = Context::new(problem);
    let mut state = State::initial(problem);
    let initial_cost = ctx.cost(&state);
    let mut cost = initial_cost;
    let mut lambda = LAMBDA_START;
    let mut accepted = 0;
    'outer: while accepted < problem.iterations && cost > 0.0 {
        let normal = ctx.linearise(&state);
        loop {
            if lambda > LAMBDA_MAX {
                break 'outer;
            }
            let Some(step) = normal.damped_step(lambda, &ctx.by_point) else {
                lambda *= 10.0;
                continue;
            };
            let trial = state.stepped(&step);
            let trial_cost = ctx.cost(&trial);
            if trial_cost < cost {
                let gain = (cost - trial_cost) / cost;
                state = trial;
                cost = trial_cost;
                accepted += 1;
                lambda = (lambda / 10.0).max(LAMBDA_MIN);
                if gain < REL_COST_TOL {
                    break 'outer;
                }
                break;
            }
            lambda *= 10.0;
        }
    }
    let reprojection_px = problem
        .observations
        .iter()
        .map(|o| {
            let uv = project(
                &state.rotations[o.camera],
                &state.centres[o.camera],
                &state.points[o.point],
                &ctx.k,
            );
            // Accepted states have every observed point in front (infinite cost otherwise).
            uv.map_or(f64::INFINITY, |uv| {
                (uv - Vector2::new(o.uv[0], o.uv[1])).norm()
            })
        })
        .collect();
    let (normal, _) = ctx.axes.normal(&state.q);
    Ok(BundleSolution {
        rotations: state.rotations,
        centres: state.centres,
        points: state.points,
        normal,
        distance: state.d,
        reprojection_px,
        iterations: accepted,
        initial_cost,
        final_cost: cost,
    })
}

fn validate(p: &BundleProblem) -> Result<(), BundleError> {
    let n = p.rotations.len();
    for (what, got) in [
        ("centres", p.centres.len()),
        ("gps_en", p.gps_en.len()),
        ("altitude", p.altitude.len()),
    ] {
        if got != n {
            return Err(BundleError::LengthMismatch {
                what,
                expected: n,
                got,
            });
        }
    }
    if !(p.focal_px.is_finite() && p.focal_px > 0.0) {
        return Err(BundleError::InvalidFocal {
            focal_px: p.focal_px,
        });
    }
    let finite = |ok: bool, what: &'static str, index: usize| {
        if ok {
            Ok(())
        } else {
            Err(BundleError::NonFinite { what, index })
        }
    };
    finite(p.cx.is_finite() && p.cy.is_finite(), "principal point", 0)?;
    for (name, value) in [
        ("gps_m", p.sigmas.gps_m),
        ("alt_m", p.sigmas.alt_m),
        ("rot_rad", p.sigmas.rot_rad),
        ("plane_m", p.sigmas.plane_m),
    ] {
        if value.is_nan() || value <= 0.0 {
            return Err(BundleError::InvalidSigma { name, value });
        }
    }
    for (c, r) in p.rotations.iter().enumerate() {
        finite(r.iter().all(|v| v.is_finite()), "rotation", c)?;
        let deviation = (r.transpose() * r - Matrix3::identity()).amax();
        let det = r.determinant();
        if deviation > ORTHO_TOL || det <= 0.0 {
            return Err(BundleError::NotARotation {
                camera: c,
                deviation,
                det,
            });
        }
    }
    for (c, x) in p.centres.iter().enumerate() {
        finite(x.iter().all(|v| v.is_finite()), "centre", c)?;
    }
    for (c, g) in p.gps_en.iter().enumerate() {
        finite(
            g.is_none_or(|g| g.iter().all(|v| v.is_finite())),
            "GPS prior",
            c,
        )?;
    }
    for (c, a) in p.altitude.iter().enumerate() {
        finite(a.is_none_or(f64::is_finite), "altitude prior", c)?;
    }
    for (j, x) in p.points.iter().enumerate() {
        finite(x.iter().all(|v| v.is_finite()), "point", j)?;
    }
    let pl = &p.plane;
    finite(
        pl.normal
            .iter()
            .chain(&pl.right)
            .chain(&pl.down)
            .all(|v| v.is_finite())
            && pl.distance.is_finite(),
        "plane",
        0,
    )?;
    let axes = Matrix3::from_columns(&[pl.normal, pl.right, pl.down]);
    let deviation = (axes.transpose() * axes - Matrix3::identity()).amax();
    if deviation > ORTHO_TOL {
        return Err(BundleError::PlaneAxes { deviation });
    }
    for (i, o) in p.observations.iter().enumerate() {
        if o.camera >= n {
            return Err(BundleError::CameraOutOfRange {
                observation: i,
                camera: o.camera,
                cameras: n,
            });
        }
        if o.point >= p.points.len() {
            return Err(BundleError::PointOutOfRange {
                observation: i,
                point: o.point,
                points: p.points.len(),
            });
        }
        finite(o.uv.iter().all(|v| v.is_finite()), "observation", i)?;
        let y = p.rotations[o.camera].transpose() * (p.points[o.point] - p.centres[o.camera]);
        // The same test as `project`'s.
        if y.z <= MIN_DEPTH_M {
            return Err(BundleError::PointBehindCamera {
                observation: i,
                camera: o.camera,
                point: o.point,
                depth_m: y.z,
            });
        }
    }
    Ok(())
}

#[derive(Debug, Clone, Copy)]
struct Intrinsics {
    f: f64,
    cx: f64,
    cy: f64,
}

/// `n₀, a, b` of the normal's parametrisation.
#[derive(Debug, Clone, Copy)]
struct PlaneAxes {
    n0: Vector3<f64>,
    a: Vector3<f64>,
    b: Vector3<f64>,
}

impl PlaneAxes {
    /// The unit normal at `q` and `∂n/∂q` (columns for q₀, q₁).
    fn normal(&self, q: &Vector2<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 2>) {
        let v = self.n0 + self.a * q.x + self.b * q.y;
        let len = v.norm();
        let n = v / len;
        let proj = (Matrix3::identity() - n * n.transpose()) / len;
        (
            n,
            SMatrix::<f64, 3, 2>::from_columns(&[proj * self.a, proj * self.b]),
        )
    }

    /// The signed distance `n·X − d`, its gradient in `X` and in `(q₀, q₁, d)`.
    fn term(
        &self,
        q: &Vector2<f64>,
        d: f64,
        x: &Vector3<f64>,
    ) -> (f64, Vector3<f64>, Vector3<f64>) {
        let (n, dn) = self.normal(q);
        let dq = dn.transpose() * x;
        (n.dot(x) - d, n, Vector3::new(dq.x, dq.y, -1.0))
    }
}

/// The projection of `x` by the camera `(r, c)`, `None` at or behind it.
fn project(
    r: &Matrix3<f64>,
    c: &Vector3<f64>,
    x: &Vector3<f64>,
    k: &Intrinsics,
) -> Option<Vector2<f64>> {
    let y = r.transpose() * (x - c);
    (y.z > MIN_DEPTH_M).then(|| Vector2::new(k.f * y.x / y.z + k.cx, k.f * y.y / y.z + k.cy))
}

/// The projection and its Jacobians: wrt the camera `(δC, δ)` (2 × 6) and the point (2 × 3).
/// `None` at or behind the camera.
fn project_jacobians(
    r: &Matrix3<f64>,
    c: &Vector3<f64>,
    x: &Vector3<f64>,
    k: &Intrinsics,
) -> Option<(Vector2<f64>, Mat2x6, Matrix2x3<f64>)> {
    let y = r.transpose() * (x - c);
    if y.z <= MIN_DEPTH_M {
        return None;
    }
    let iz = 1.0 / y.z;
    let uv = Vector2::new(k.f * y.x * iz + k.cx, k.f * y.y * iz + k.cy);
    let dpi = Matrix2x3::new(
        k.f * iz,
        0.0,
        -k.f * y.x * iz * iz,
        0.0,
        k.f * iz,
        -k.f * y.y * iz * iz,
    );
    let j_point = dpi * r.transpose();
    // y(δ) = exp(−δ)·y ≈ y + [y]×δ.
    let j_rot = dpi * skew(&y);
    let mut j_cam = Mat2x6::zeros();
    j_cam.fixed_view_mut::<2, 3>(0, 0).copy_from(&(-j_point));
    j_cam.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_rot);
    Some((uv, j_cam, j_point))
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `exp([w]×)` (Rodrigues).
fn exp_so3(w: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = w.norm_squared();
    let (a, b) = if t2 < 1e-12 {
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0)
    } else {
        let t = t2.sqrt();
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    let k = skew(w);
    Matrix3::identity() + k * a + k * k * b
}

/// `log` of a rotation matrix as a rotation vector, through the quaternion (accurate at small
/// angles and up to π).
fn log_so3(r: &Matrix3<f64>) -> Vector3<f64> {
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(*r),
    );
    let (mut w, mut v) = (q.w, q.imag());
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let s = v.norm();
    if s < 1e-12 {
        // θ/s → 2/w.
        v * (2.0 / w)
    } else {
        v * (2.0 * s.atan2(w) / s)
    }
}

/// The rotation prior's residual `φ = log(R₀ᵀR)` and `∂φ/∂δ = J_r⁻¹(φ)` for `R ← R·exp(δ)`.
fn rotation_prior(r0: &Matrix3<f64>, r: &Matrix3<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let phi = log_so3(&(r0.transpose() * r));
    let t2 = phi.norm_squared();
    let c = if t2 < 1e-8 {
        1.0 / 12.0 + t2 / 720.0
    } else {
        let t = t2.sqrt();
        1.0 / t2 - (1.0 + t.cos()) / (2.0 * t * t.sin())
    };
    let k = skew(&phi);
    (phi, Matrix3::identity() + k * 0.5 + k * k * c)
}

/// Huber's `ρₖ` of a normalised residual `e ≥ 0`.
fn huber_cost(e: f64, k: f64) -> f64 {
    if e <= k { e * e } else { 2.0 * k * e - k * k }
}

/// The IRLS weight of Huber's loss: `min(1, k/e)`.
fn huber_weight(e: f64, k: f64) -> f64 {
    if e <= k { 1.0 } else { k / e }
}

/// The Geman–McClure loss `c²e²/(c² + e²)` of a normalised residual `e` (≈ `e²` near 0,
/// bounded by `c²`).
fn geman_mcclure_cost(e: f64, c: f64) -> f64 {
    let (e2, c2) = (e * e, c * c);
    c2 * e2 / (c2 + e2)
}

/// The IRLS weight of the Geman–McClure loss: its derivative in `e²`, `(c²/(c² + e²))²`.
fn geman_mcclure_weight(e: f64, c: f64) -> f64 {
    let c2 = c * c;
    (c2 / (c2 + e * e)).powi(2)
}

/// `1/σ²`, 0 for an infinite σ (term dropped).
fn info(sigma: f64) -> f64 {
    1.0 / (sigma * sigma)
}

/// The unknowns.
#[derive(Debug, Clone)]
struct State {
    rotations: Vec<Matrix3<f64>>,
    centres: Vec<Vector3<f64>>,
    points: Vec<Vector3<f64>>,
    q: Vector2<f64>,
    d: f64,
}

impl State {
    fn initial(p: &BundleProblem) -> Self {
        Self {
            rotations: p.rotations.clone(),
            centres: p.centres.clone(),
            points: p.points.clone(),
            q: Vector2::zeros(),
            d: p.plane.distance,
        }
    }

    /// The state moved by a step in [`Normal`]'s order (cameras, plane, points).
    fn stepped(&self, step: &DVector<f64>) -> Self {
        let nc = self.centres.len();
        let mut next = self.clone();
        for c in 0..nc {
            let o = 6 * c;
            next.centres[c] += Vector3::new(step[o], step[o + 1], step[o + 2]);
            next.rotations[c] =
                self.rotations[c] * exp_so3(&Vector3::new(step[o + 3], step[o + 4], step[o + 5]));
        }
        let o = 6 * nc;
        next.q += Vector2::new(step[o], step[o + 1]);
        next.d += step[o + 2];
        for (j, x) in next.points.iter_mut().enumerate() {
            let o = 6 * nc + 3 + 3 * j;
            *x += Vector3::new(step[o], step[o + 1], step[o + 2]);
        }
        next
    }
}

/// The problem's constants and indices.
#[derive(Debug)]
struct Context<'a> {
    p: &'a BundleProblem,
    k: Intrinsics,
    axes: PlaneAxes,
    /// Observation indices of each point.
    by_point: Vec<Vec<usize>>,
}

impl<'a> Context<'a> {
    fn new(p: &'a BundleProblem) -> Self {
        let mut by_point = vec![Vec::new(); p.points.len()];
        for (i, o) in p.observations.iter().enumerate() {
            by_point[o.point].push(i);
        }
        Self {
            p,
            k: Intrinsics {
                f: p.focal_px,
                cx: p.cx,
                cy: p.cy,
            },
            axes: PlaneAxes {
                n0: p.plane.normal,
                a: p.plane.right,
                b: p.plane.down,
            },
            by_point,
        }
    }

    /// The robust cost (module docs); infinite when an observed point is behind its camera.
    fn cost(&self, s: &State) -> f64 {
        let p = self.p;
        let mut cost = 0.0;
        for o in &p.observations {
            let Some(uv) = project(
                &s.rotations[o.camera],
                &s.centres[o.camera],
                &s.points[o.point],
                &self.k,
            ) else {
                return f64::INFINITY;
            };
            let e = (uv - Vector2::new(o.uv[0], o.uv[1])).norm();
            cost += huber_cost(e, HUBER_PX);
        }
        if p.sigmas.plane_m.is_finite() {
            let (n, _) = self.axes.normal(&s.q);
            for x in &s.points {
                let e = (n.dot(x) - s.d).abs() / p.sigmas.plane_m;
                cost += geman_mcclure_cost(e, PLANE_SCALE_SIGMAS);
            }
        }
        let (i_gps, i_alt, i_rot) = (
            info(p.sigmas.gps_m),
            info(p.sigmas.alt_m),
            info(p.sigmas.rot_rad),
        );
        for (c, centre) in s.centres.iter().enumerate() {
            if let Some(g) = p.gps_en[c] {
                cost += i_gps * ((centre.x - g[0]).powi(2) + (centre.y - g[1]).powi(2));
            }
            if let Some(a) = p.altitude[c] {
                cost += i_alt * (centre.z - a).powi(2);
            }
            if i_rot > 0.0 {
                let phi = log_so3(&(p.rotations[c].transpose() * s.rotations[c]));
                cost += i_rot * phi.norm_squared();
            }
        }
        cost
    }

    /// The IRLS-weighted normal equations at `s` (weights from `s`'s residuals).
    fn linearise(&self, s: &State) -> Normal {
        let p = self.p;
        let (nc, np) = (s.centres.len(), s.points.len());
        let mut n = Normal {
            u: vec![Mat6::zeros(); nc],
            gu: vec![Vec6::zeros(); nc],
            pl: Matrix3::zeros(),
            gpl: Vector3::zeros(),
            v: vec![Matrix3::zeros(); np],
            gv: vec![Vector3::zeros(); np],
            w: vec![Mat6x3::zeros(); p.observations.len()],
            obs_cam: p.observations.iter().map(|o| o.camera).collect(),
            y: vec![Matrix3::zeros(); np],
        };
        for (i, o) in p.observations.iter().enumerate() {
            let (c, j) = (o.camera, o.point);
            // Accepted states have every observed point in front; were one not, it would
            // simply carry no information at this linearisation.
            let Some((uv, jc, jp)) =
                project_jacobians(&s.rotations[c], &s.centres[c], &s.points[j], &self.k)
            else {
                continue;
            };
            let r = uv - Vector2::new(o.uv[0], o.uv[1]);
            let w = huber_weight(r.norm(), HUBER_PX);
            let jct = jc.transpose() * w;
            let jpt = jp.transpose() * w;
            n.u[c] += jct * jc;
            n.gu[c] += jct * r;
            n.v[j] += jpt * jp;
            n.gv[j] += jpt * r;
            n.w[i] = jct * jp;
        }
        if p.sigmas.plane_m.is_finite() {
            let sigma = p.sigmas.plane_m;
            for (j, x) in s.points.iter().enumerate() {
                let (r, dx, dpl) = self.axes.term(&s.q, s.d, x);
                let w = geman_mcclure_weight(r.abs() / sigma, PLANE_SCALE_SIGMAS) * info(sigma);
                n.v[j] += dx * dx.transpose() * w;
                n.gv[j] += dx * (w * r);
                n.pl += dpl * dpl.transpose() * w;
                n.gpl += dpl * (w * r);
                n.y[j] = dpl * dx.transpose() * w;
            }
        }
        let (i_gps, i_alt, i_rot) = (
            info(p.sigmas.gps_m),
            info(p.sigmas.alt_m),
            info(p.sigmas.rot_rad),
        );
        for c in 0..nc {
            let centre = s.centres[c];
            if let Some(g) = p.gps_en[c] {
                n.u[c][(0, 0)] += i_gps;
                n.u[c][(1, 1)] += i_gps;
                n.gu[c][0] += i_gps * (centre.x - g[0]);
                n.gu[c][1] += i_gps * (centre.y - g[1]);
            }
            if let Some(a) = p.altitude[c] {
                n.u[c][(2, 2)] += i_alt;
                n.gu[c][2] += i_alt * (centre.z - a);
            }
            if i_rot > 0.0 {
                let (phi, jr) = rotation_prior(&p.rotations[c], &s.rotations[c]);
                let jrt = jr.transpose() * i_rot;
                let mut blk = n.u[c].fixed_view_mut::<3, 3>(3, 3);
                blk += jrt * jr;
                let mut g = n.gu[c].fixed_rows_mut::<3>(3);
                g += jrt * phi;
            }
        }
        n
    }
}

/// The normal equations `H δ = −g` in blocks (module docs). Parameter order: camera `c` at
/// `6c..6c+6` (`δC`, `δ`), the plane at `6·cameras..+3` (`q₀, q₁, d`), point `j` at
/// `6·cameras + 3 + 3j..+3`.
#[derive(Debug, Clone)]
struct Normal {
    /// Camera blocks of `U` and their gradients.
    u: Vec<Mat6>,
    gu: Vec<Vec6>,
    /// Plane block of `U` and its gradient.
    pl: Matrix3<f64>,
    gpl: Vector3<f64>,
    /// Point blocks `V` and their gradients.
    v: Vec<Matrix3<f64>>,
    gv: Vec<Vector3<f64>>,
    /// Camera–point coupling of each observation (rows: camera, columns: point).
    w: Vec<Mat6x3>,
    /// The camera of each observation.
    obs_cam: Vec<usize>,
    /// Plane–point coupling of each point (rows: plane, columns: point).
    y: Vec<Matrix3<f64>>,
}

/// `m` with Marquardt's damping on its diagonal (module docs).
fn damped<const N: usize>(m: &SMatrix<f64, N, N>, lambda: f64) -> SMatrix<f64, N, N> {
    let mut d = *m;
    for i in 0..N {
        d[(i, i)] = damp(m[(i, i)], lambda);
    }
    d
}

fn damp(x: f64, lambda: f64) -> f64 {
    x + lambda * x.max(DAMP_FLOOR)
}

impl Normal {
    /// The Marquardt step, `(H + λ·diag H) δ = −g`, through the Schur complement on cameras and
    /// plane. `None` when a damped block is not positive definite (the caller raises λ).
    fn damped_step(&self, lambda: f64, by_point: &[Vec<usize>]) -> Option<DVector<f64>> {
        let nc = self.u.len();
        let po = 6 * nc; // the plane's offset
        let red = po + 3;
        let mut s = DMatrix::<f64>::zeros(red, red);
        let mut rhs = DVector::<f64>::zeros(red);
        for c in 0..nc {
            s.fixed_view_mut::<6, 6>(6 * c, 6 * c)
                .copy_from(&damped(&self.u[c], lambda));
            rhs.fixed_rows_mut::<6>(6 * c).copy_from(&(-self.gu[c]));
        }
        s.fixed_view_mut::<3, 3>(po, po)
            .copy_from(&damped(&self.pl, lambda));
        rhs.fixed_rows_mut::<3>(po).copy_from(&(-self.gpl));

        let mut v_inv = Vec::with_capacity(self.v.len());
        for (j, obs) in by_point.iter().enumerate() {
            let vi = damped(&self.v[j], lambda).cholesky()?.inverse();
            let vg = vi * self.gv[j];
            let y = &self.y[j];
            let yvi = y * vi;
            for &a in obs {
                let ca = 6 * self.obs_cam[a];
                let wvi = self.w[a] * vi;
                let mut r = rhs.fixed_rows_mut::<6>(ca);
                r += self.w[a] * vg;
                for &b in obs {
                    let cb = 6 * self.obs_cam[b];
                    let mut blk = s.fixed_view_mut::<6, 6>(ca, cb);
                    blk -= wvi * self.w[b].transpose();
                }
                let cp = wvi * y.transpose();
                let mut blk = s.fixed_view_mut::<6, 3>(ca, po);
                blk -= cp;
                let mut blk = s.fixed_view_mut::<3, 6>(po, ca);
                blk -= cp.transpose();
            }
            let mut r = rhs.fixed_rows_mut::<3>(po);
            r += y * vg;
            let mut blk = s.fixed_view_mut::<3, 3>(po, po);
            blk -= yvi * y.transpose();
            v_inv.push(vi);
        }

        let x = s.cholesky()?.solve(&rhs);
        let mut step = DVector::zeros(red + 3 * self.v.len());
        step.rows_mut(0, red).copy_from(&x);
        let x_plane = x.fixed_rows::<3>(po).into_owned();
        for (j, obs) in by_point.iter().enumerate() {
            // V δ_j = −g_j − Wᵀ δ_cam − Yᵀ δ_plane.
            let mut b = -self.gv[j] - self.y[j].transpose() * x_plane;
            for &a in obs {
                let xc = x.fixed_rows::<6>(6 * self.obs_cam[a]);
                b -= self.w[a].transpose() * xc;
            }
            step.fixed_rows_mut::<3>(red + 3 * j)
                .copy_from(&(v_inv[j] * b));
        }
        Some(step)
    }

    /// The full dense `H` and `g` in the same order (tests).
    #[cfg(test)]
    fn dense(&self, by_point: &[Vec<usize>]) -> (DMatrix<f64>, DVector<f64>) {
        let nc = self.u.len();
        let po = 6 * nc;
        let n = po + 3 + 3 * self.v.len();
        let mut h = DMatrix::zeros(n, n);
        let mut g = DVector::zeros(n);
        for c in 0..nc {
            h.fixed_view_mut::<6, 6>(6 * c, 6 * c).copy_from(&self.u[c]);
            g.fixed_rows_mut::<6>(6 * c).copy_from(&self.gu[c]);
        }
        h.fixed_view_mut::<3, 3>(po, po).copy_from(&self.pl);
        g.fixed_rows_mut::<3>(po).copy_from(&self.gpl);
        for (j, obs) in by_point.iter().enumerate() {
            let pj = po + 3 + 3 * j;
            h.fixed_view_mut::<3, 3>(pj, pj).copy_from(&self.v[j]);
            g.fixed_rows_mut::<3>(pj).copy_from(&self.gv[j]);
            h.fixed_view_mut::<3, 3>(po, pj).copy_from(&self.y[j]);
            h.fixed_view_mut::<3, 3>(pj, po)
                .copy_from(&self.y[j].transpose());
            for &a in obs {
                let ca = 6 * self.obs_cam[a];
                let mut blk = h.fixed_view_mut::<6, 3>(ca, pj);
                blk += self.w[a];
                let mut blk = h.fixed_view_mut::<3, 6>(pj, ca);
                blk += self.w[a].transpose();
            }
        }
        (h, g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal as Gauss};

    const F: f64 = 500.0;
    const W: f64 = 640.0;
    const H: f64 = 512.0;

    /// world_from_cam of a level camera looking north: x east, y down, z north.
    fn looking_north() -> Matrix3<f64> {
        Matrix3::from_columns(&[
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.0, 1.0, 0.0),
        ])
    }

    fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
        let g = Gauss::new(0.0, 1.0).unwrap_or_else(|e| panic!("{e}"));
        let v = Vector3::new(g.sample(rng), g.sample(rng), g.sample(rng));
        v / v.norm()
    }

    struct Truth {
        rotations: Vec<Matrix3<f64>>,
        centres: Vec<Vector3<f64>>,
        points: Vec<Vector3<f64>>,
        normal: Vector3<f64>,
    }

    struct Synth {
        cols: usize,
        rows: usize,
        spacing_m: f64,
        points: usize,
        max_views: usize,
        /// Perturbations of the initial values (random directions): centres (m), rotations (°),
        /// points (m).
        centre_m: f64,
        rot_deg: f64,
        point_m: f64,
        /// σ of the GPS and altitude priors' noise (and the priors' σ, at least 1 mm).
        gps_noise_m: f64,
        pixel_noise_px: f64,
        /// Fraction of the points 0.3 m in front of the wall.
        off_plane: f64,
        seed: u64,
    }

    impl Default for Synth {
        fn default() -> Self {
            Self {
                cols: 6,
                rows: 5,
                spacing_m: 1.0,
                points: 600,
                max_views: 3,
                centre_m: 0.3,
                rot_deg: 1.0,
                point_m: 0.1,
                // Survey-grade centre priors: a camera's rotation about the wall's in-plane axes
                // is only as good as its centre along the wall / 3 m (module docs, "Expected
                // accuracy"), and the rotation check is 0.2°. With 2 cm priors the worst camera
                // is 0.25–0.45° off (0.3° σ per camera by the covariance).
                gps_noise_m: 0.001,
                pixel_noise_px: 0.1,
                off_plane: 0.15,
                seed: 1,
            }
        }
    }

    /// Cameras on a `cols × rows` grid at north 0 looking north at the wall north = 3 (points
    /// on it, 15 % of them 0.3 m in front of it), each point seen by 2..=max_views cameras.
    fn synthetic(s: &Synth) -> (BundleProblem, Truth) {
        let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
        let px = Gauss::new(0.0, s.pixel_noise_px).unwrap_or_else(|e| panic!("{e}"));
        let gps = Gauss::new(0.0, s.gps_noise_m).unwrap_or_else(|e| panic!("{e}"));
        let k = Intrinsics {
            f: F,
            cx: W / 2.0,
            cy: H / 2.0,
        };
        let mut rotations = Vec::new();
        let mut centres = Vec::new();
        for r in 0..s.rows {
            for c in 0..s.cols {
                rotations.push(looking_north());
                centres.push(Vector3::new(
                    c as f64 * s.spacing_m,
                    0.0,
                    r as f64 * s.spacing_m,
                ));
            }
        }
        let n = centres.len();
        let (xmax, zmax) = (
            (s.cols - 1) as f64 * s.spacing_m,
            (s.rows - 1) as f64 * s.spacing_m,
        );
        let mut points = Vec::new();
        let mut observations = Vec::new();
        while points.len() < s.points {
            let north = if rng.random_bool(s.off_plane) {
                2.7
            } else {
                3.0
            };
            let x = Vector3::new(
                rng.random_range(-1.0..xmax + 1.0),
                north,
                rng.random_range(-0.8..zmax + 0.8),
            );
            let mut seen: Vec<(usize, Vector2<f64>)> = (0..n)
                .filter_map(|c| {
                    let uv = project(&rotations[c], &centres[c], &x, &k)?;
                    (uv.x > 5.0 && uv.x < W - 5.0 && uv.y > 5.0 && uv.y < H - 5.0)
                        .then_some((c, uv))
                })
                .collect();
            if seen.len() < 2 {
                continue;
            }
            let views = rng.random_range(2..=s.max_views.min(seen.len()));
            let j = points.len();
            for _ in 0..views {
                let (c, uv) = seen.swap_remove(rng.random_range(0..seen.len()));
                observations.push(Observation {
                    camera: c,
                    point: j,
                    uv: [uv.x + px.sample(&mut rng), uv.y + px.sample(&mut rng)],
                });
            }
            points.push(x);
        }
        let truth = Truth {
            rotations: rotations.clone(),
            centres: centres.clone(),
            points: points.clone(),
            normal: Vector3::new(0.0, 1.0, 0.0),
        };
        let gps_en = centres
            .iter()
            .map(|c| Some([c.x + gps.sample(&mut rng), c.y + gps.sample(&mut rng)]))
            .collect();
        let altitude = centres
            .iter()
            .map(|c| Some(c.z + gps.sample(&mut rng)))
            .collect();
        let rotations = rotations
            .iter()
            .map(|r| r * exp_so3(&(random_unit(&mut rng) * s.rot_deg.to_radians())))
            .collect();
        let centres = centres
            .iter()
            .map(|c| c + random_unit(&mut rng) * s.centre_m)
            .collect();
        let points = points
            .iter()
            .map(|x| x + random_unit(&mut rng) * s.point_m)
            .collect();
        // The reference orientation is 2° off the wall's (yaw and pitch).
        let reference =
            exp_so3(&Vector3::new(1.5f64.to_radians(), 0.0, 1.5f64.to_radians())) * looking_north();
        let problem = BundleProblem {
            focal_px: F,
            cx: W / 2.0,
            cy: H / 2.0,
            rotations,
            centres,
            gps_en,
            altitude,
            points,
            observations,
            plane: PlaneInit {
                normal: reference.column(2).into_owned(),
                right: reference.column(0).into_owned(),
                down: reference.column(1).into_owned(),
                distance: 3.05,
            },
            sigmas: Sigmas {
                gps_m: s.gps_noise_m.max(1e-3),
                alt_m: s.gps_noise_m.max(1e-3),
                rot_rad: s.rot_deg.max(0.1).to_radians(),
                plane_m: 0.05,
            },
            iterations: 20,
        };
        (problem, truth)
    }

    fn median(v: &[f64]) -> f64 {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    }

    fn initial_errors(p: &BundleProblem) -> Vec<f64> {
        let k = Intrinsics {
            f: p.focal_px,
            cx: p.cx,
            cy: p.cy,
        };
        p.observations
            .iter()
            .map(|o| {
                let uv = project(
                    &p.rotations[o.camera],
                    &p.centres[o.camera],
                    &p.points[o.point],
                    &k,
                )
                .unwrap_or_else(|| panic!("behind"));
                (uv - Vector2::new(o.uv[0], o.uv[1])).norm()
            })
            .collect()
    }

    fn angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
        log_so3(&(a.transpose() * b)).norm().to_degrees()
    }

    fn check_against_truth(sol: &BundleSolution, truth: &Truth, skip: &[usize]) {
        let kept: Vec<f64> = sol
            .reprojection_px
            .iter()
            .enumerate()
            .filter(|(i, _)| !skip.contains(i))
            .map(|(_, e)| *e)
            .collect();
        let med = median(&kept);
        assert!(
            med <= 0.2,
            "final median reprojection {med} px, expected ≤ 0.2"
        );
        let worst_centre = sol
            .centres
            .iter()
            .zip(&truth.centres)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(
            worst_centre < 0.1,
            "worst centre error {worst_centre} m, expected < 0.1"
        );
        let worst_rot = sol
            .rotations
            .iter()
            .zip(&truth.rotations)
            .map(|(a, b)| angle_deg(a, b))
            .fold(0.0, f64::max);
        assert!(
            worst_rot < 0.2,
            "worst rotation error {worst_rot}°, expected < 0.2°"
        );
        let normal_deg = sol
            .normal
            .dot(&truth.normal)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        assert!(
            normal_deg < 0.5,
            "plane normal {normal_deg}° off, expected < 0.5°"
        );
        assert!(
            (sol.distance - 3.0).abs() < 0.05,
            "plane distance {} m, expected 3 ± 0.05",
            sol.distance
        );
    }

    #[test]
    fn synthetic_facade_converges_to_the_truth() {
        let (problem, truth) = synthetic(&Synth::default());
        let before = median(&initial_errors(&problem));
        assert!(
            before > 2.0,
            "initial median reprojection {before} px, expected > 2"
        );
        let sol = solve(&problem).unwrap_or_else(|e| panic!("{e}"));
        assert!(sol.final_cost < sol.initial_cost);
        check_against_truth(&sol, &truth, &[]);
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let k = Intrinsics {
            f: 480.0,
            cx: 320.0,
            cy: 250.0,
        };
        let r = exp_so3(&Vector3::new(0.1, -0.2, 0.05)) * looking_north();
        let c = Vector3::new(0.3, -0.2, 1.1);
        let x = Vector3::new(1.0, 3.2, 0.4);
        let (_, jc, jp) = project_jacobians(&r, &c, &x, &k).unwrap_or_else(|| panic!("behind"));
        let h = 1e-6;
        let proj = |r: &Matrix3<f64>, c: &Vector3<f64>, x: &Vector3<f64>| {
            project(r, c, x, &k).unwrap_or_else(|| panic!("behind"))
        };
        let close = |analytic: f64, numeric: f64, what: &str| {
            assert!(
                (analytic - numeric).abs() <= 1e-6 * (1.0 + numeric.abs()),
                "{what}: analytic {analytic}, finite difference {numeric}"
            );
        };
        for i in 0..3 {
            let e = Vector3::ith(i, h);
            let dc = (proj(&r, &(c + e), &x) - proj(&r, &(c - e), &x)) / (2.0 * h);
            let dr =
                (proj(&(r * exp_so3(&e)), &c, &x) - proj(&(r * exp_so3(&-e)), &c, &x)) / (2.0 * h);
            let dx = (proj(&r, &c, &(x + e)) - proj(&r, &c, &(x - e))) / (2.0 * h);
            for a in 0..2 {
                close(jc[(a, i)], dc[a], &format!("∂uv{a}/∂C{i}"));
                close(jc[(a, 3 + i)], dr[a], &format!("∂uv{a}/∂δ{i}"));
                close(jp[(a, i)], dx[a], &format!("∂uv{a}/∂X{i}"));
            }
        }

        let frame = exp_so3(&Vector3::new(0.02, 0.3, -0.1));
        let axes = PlaneAxes {
            n0: frame.column(2).into_owned(),
            a: frame.column(0).into_owned(),
            b: frame.column(1).into_owned(),
        };
        let q = Vector2::new(0.15, -0.1);
        let d = 2.5;
        let x = Vector3::new(0.7, -1.3, 2.9);
        let (_, dx, dpl) = axes.term(&q, d, &x);
        for i in 0..3 {
            let e = Vector3::ith(i, h);
            let num = (axes.term(&q, d, &(x + e)).0 - axes.term(&q, d, &(x - e)).0) / (2.0 * h);
            close(dx[i], num, &format!("∂s/∂X{i}"));
        }
        for i in 0..2 {
            let e = Vector2::ith(i, h);
            let num = (axes.term(&(q + e), d, &x).0 - axes.term(&(q - e), d, &x).0) / (2.0 * h);
            close(dpl[i], num, &format!("∂s/∂q{i}"));
        }
        let num = (axes.term(&q, d + h, &x).0 - axes.term(&q, d - h, &x).0) / (2.0 * h);
        close(dpl[2], num, "∂s/∂d");

        let r0 = looking_north();
        let r = r0 * exp_so3(&Vector3::new(0.3, -0.2, 0.4));
        let (_, jr) = rotation_prior(&r0, &r);
        for i in 0..3 {
            let e = Vector3::ith(i, h);
            let num = (rotation_prior(&r0, &(r * exp_so3(&e))).0
                - rotation_prior(&r0, &(r * exp_so3(&-e))).0)
                / (2.0 * h);
            for a in 0..3 {
                close(jr[(a, i)], num[a], &format!("∂φ{a}/∂δ{i}"));
            }
        }
    }

    #[test]
    fn schur_step_equals_the_dense_solve() {
        let (problem, _) = synthetic(&Synth {
            cols: 2,
            rows: 2,
            points: 10,
            ..Synth::default()
        });
        assert_eq!(problem.centres.len(), 4);
        let ctx = Context::new(&problem);
        let normal = ctx.linearise(&State::initial(&problem));
        let (h, g) = normal.dense(&ctx.by_point);
        for lambda in [1e-9, 1e-3, 10.0] {
            let mut a = h.clone();
            for i in 0..a.nrows() {
                a[(i, i)] = damp(h[(i, i)], lambda);
            }
            let dense = a
                .cholesky()
                .unwrap_or_else(|| panic!("dense system not positive definite"))
                .solve(&(-&g));
            let schur = normal
                .damped_step(lambda, &ctx.by_point)
                .unwrap_or_else(|| panic!("Schur step failed for λ = {lambda}"));
            let err = (&schur - &dense).amax() / dense.amax();
            assert!(
                err < 1e-8,
                "λ {lambda}: Schur step differs from the dense solve by {err:e} (relative)"
            );
        }
    }

    /// Noise-free pixels and priors at the truth (no rotation prior: its centre is perturbed),
    /// all points on the wall: the truth is the exact minimum and must be reached to rounding.
    #[test]
    fn noise_free_data_is_fitted_exactly() {
        let (mut problem, truth) = synthetic(&Synth {
            gps_noise_m: 0.0,
            pixel_noise_px: 0.0,
            off_plane: 0.0,
            ..Synth::default()
        });
        problem.sigmas.rot_rad = f64::INFINITY;
        problem.iterations = 50;
        let sol = solve(&problem).unwrap_or_else(|e| panic!("{e}"));
        let worst_px = sol.reprojection_px.iter().copied().fold(0.0, f64::max);
        let worst_centre = sol
            .centres
            .iter()
            .zip(&truth.centres)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        let worst_rot = sol
            .rotations
            .iter()
            .zip(&truth.rotations)
            .map(|(a, b)| angle_deg(a, b))
            .fold(0.0, f64::max);
        let worst_point = sol
            .points
            .iter()
            .zip(&truth.points)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(
            worst_px < 1e-6 && worst_centre < 1e-8 && worst_rot < 1e-6 && worst_point < 1e-8,
            "not exact: {worst_px:e} px, centres {worst_centre:e} m, rotations {worst_rot:e}°, points {worst_point:e} m"
        );
        assert!(
            (sol.normal - truth.normal).norm() < 1e-9 && (sol.distance - 3.0).abs() < 1e-9,
            "plane not exact: {:?}, {}",
            sol.normal,
            sol.distance
        );
    }

    #[test]
    fn gross_outliers_do_not_pull_the_solution() {
        let (mut problem, truth) = synthetic(&Synth {
            seed: 7,
            ..Synth::default()
        });
        // One view of every 15th point seen three times moved by 50 px. (With two views, an
        // outlier along the epipolar line is a point off the wall: undetectable, and absorbed
        // by that point without pulling the cameras.)
        let by_point = Context::new(&problem).by_point;
        let outliers: Vec<usize> = by_point
            .iter()
            .filter(|obs| obs.len() == 3)
            .step_by(15)
            .map(|obs| obs[0])
            .collect();
        assert!(outliers.len() >= 8, "only {} outliers", outliers.len());
        for (n, &i) in outliers.iter().enumerate() {
            let angle = n as f64;
            problem.observations[i].uv[0] += 50.0 * angle.cos();
            problem.observations[i].uv[1] += 50.0 * angle.sin();
        }
        let sol = solve(&problem).unwrap_or_else(|e| panic!("{e}"));
        check_against_truth(&sol, &truth, &outliers);
        for &i in &outliers {
            let e = sol.reprojection_px[i];
            assert!(
                e > 15.0,
                "outlier observation {i} (moved by 50 px) fitted to {e} px, expected > 15"
            );
        }
    }

    #[test]
    fn invalid_input_is_named() {
        let (problem, _) = synthetic(&Synth {
            cols: 2,
            rows: 2,
            points: 10,
            ..Synth::default()
        });
        let mut p = problem.clone();
        p.observations[3].camera = 99;
        match solve(&p) {
            Err(BundleError::CameraOutOfRange {
                observation: 3,
                camera: 99,
                cameras: 4,
            }) => {}
            other => panic!("expected CameraOutOfRange for observation 3, got {other:?}"),
        }
        let mut p = problem.clone();
        p.observations[5].point = 10;
        assert!(matches!(
            solve(&p),
            Err(BundleError::PointOutOfRange {
                observation: 5,
                point: 10,
                points: 10
            })
        ));
        let mut p = problem.clone();
        let o = p.observations[2];
        p.points[o.point].y = -1.0;
        match solve(&p) {
            Err(BundleError::PointBehindCamera { camera, point, .. }) if point == o.point => {
                assert!(
                    p.observations
                        .iter()
                        .any(|x| x.point == point && x.camera == camera)
                )
            }
            other => panic!(
                "expected PointBehindCamera for point {}, got {other:?}",
                o.point
            ),
        }
        let mut p = problem.clone();
        p.points[1].x = f64::NAN;
        assert!(matches!(
            solve(&p),
            Err(BundleError::NonFinite { index: 1, .. })
        ));
        let mut p = problem;
        p.altitude.pop();
        assert!(matches!(
            solve(&p),
            Err(BundleError::LengthMismatch {
                what: "altitude",
                ..
            })
        ));
    }

    #[test]
    fn a_camera_without_information_stays_put() {
        let (mut problem, truth) = synthetic(&Synth::default());
        problem.sigmas.rot_rad = f64::INFINITY;
        let r = looking_north();
        let c = Vector3::new(10.0, -5.0, 2.0);
        problem.rotations.push(r);
        problem.centres.push(c);
        problem.gps_en.push(None);
        problem.altitude.push(None);
        let sol = solve(&problem).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(sol.centres.len(), 31);
        assert!((sol.centres[30] - c).norm() < 1e-9 && angle_deg(&sol.rotations[30], &r) < 1e-9);
        let med = median(&sol.reprojection_px);
        assert!(
            med <= 0.2,
            "final median reprojection {med} px, expected ≤ 0.2"
        );
        let worst = sol.centres[..30]
            .iter()
            .zip(&truth.centres)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(worst < 0.1, "worst centre error {worst} m");
    }

    /// The size of a real folder: 90 cameras, 900 points, 1800 observations. Times the solve
    /// (it converges in fewer than 20 iterations) and 20 full iterations' work (linearisation,
    /// Schur step, cost) on their own. `cargo test -p s3tir-calib --lib bundle_timing --
    /// --ignored --nocapture` (add `--release` for the optimised figure).
    #[test]
    #[ignore]
    fn bundle_timing() {
        let (problem, truth) = synthetic(&Synth {
            cols: 15,
            rows: 6,
            points: 900,
            max_views: 2,
            seed: 3,
            ..Synth::default()
        });
        let t = std::time::Instant::now();
        let sol = solve(&problem).unwrap_or_else(|e| panic!("{e}"));
        let dt = t.elapsed().as_secs_f64();
        let ctx = Context::new(&problem);
        let state = State::initial(&problem);
        let t = std::time::Instant::now();
        for _ in 0..20 {
            let normal = ctx.linearise(&state);
            let step = normal
                .damped_step(1e-3, &ctx.by_point)
                .unwrap_or_else(|| panic!("step failed"));
            std::hint::black_box(ctx.cost(&state.stepped(&step)));
        }
        let dt20 = t.elapsed().as_secs_f64();
        println!(
            "{} cameras, {} points, {} observations: solve {dt:.3} s ({} iterations, cost {:.1} → {:.1}); 20 iterations' work {dt20:.3} s",
            problem.centres.len(),
            problem.points.len(),
            problem.observations.len(),
            sol.iterations,
            sol.initial_cost,
            sol.final_cost
        );
        check_against_truth(&sol, &truth, &[]);
    }
}
