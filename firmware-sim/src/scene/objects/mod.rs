//! The scenes' content: every surface of both layouts with its temperature, emissivity and
//! colour ([`SceneObject`], the `ENV_K` surroundings they reflect), the ray tracer that finds
//! them ([`trace`]) and the coloured points sampled on them ([`sample_surface_points`]).
//! Geometry and materials are described in the [`super`] module docs.

use glam::DVec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::SceneLayout;

pub mod facade;

/// Temperature of the surroundings every surface reflects, kelvin.
pub const ENV_K: f64 = 290.0;
/// Apparent temperature of rays that hit nothing, kelvin.
pub const BACKGROUND_K: f64 = 285.0;
pub(super) const BACKGROUND_RGB: [f64; 3] = [0.30, 0.34, 0.40];

/// What a ray hits.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceHit {
    /// Ray parameter: distance along the (unit-z) camera ray, i.e. depth if the ray has z = 1.
    pub t: f64,
    pub temp_k: f64,
    pub emissivity: f64,
    pub albedo: [f64; 3],
    /// Unit normal facing the ray origin (world frame).
    pub normal: DVec3,
    /// The object hit.
    pub object: SceneObject,
}

/// Which object a ray hit (ground truth for masks in tests and tools).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneObject {
    Ground,
    /// The pipe's cylindrical side.
    PipeSide,
    /// One of the pipe's two end caps.
    PipeCap,
    /// The box: painted (x < [`BOX_C`].x) or bare metal.
    Box,
    Radiator,
    /// The wall of the `Wall` layout: painted (x < [`WALL_EDGE_X`]) or bare metal.
    Wall,
    /// The `Facade` layout ([`facade`]): a brick, a mortar joint, the surface-mounted
    /// pipe, the cabinet's paint and its foil labels.
    Brick,
    Mortar,
    SurfacePipe,
    Cabinet,
    Label,
}

/// Pipe extent along x, metres.
pub const PIPE_X: (f64, f64) = (-0.6, 0.6);
/// Pipe radius, metres.
pub const PIPE_R: f64 = 0.15;
/// Pipe axis (y, z), metres.
pub const PIPE_YZ: (f64, f64) = (0.3, 0.3);
/// Box centre, metres; the emissivity edge is the plane x = `BOX_C.x`.
pub const BOX_C: DVec3 = DVec3::new(0.0, -0.35, 0.15);
/// Box half-size, metres.
pub const BOX_H: f64 = 0.15;
/// Underfloor heating pipe: the floor's warm stripe is centred on x = `FLOOR_PIPE_X`, metres.
pub const FLOOR_PIPE_X: f64 = 0.7;
/// Width parameter σ of the warm stripe `exp(−((x − FLOOR_PIPE_X)/σ)²)`, metres.
pub const FLOOR_PIPE_SIGMA: f64 = 0.12;
/// Peak warming of the floor surface above the pipe, kelvin.
pub const FLOOR_PIPE_PEAK_K: f64 = 9.0;

/// Floor surface temperature at `x` (291 K plus the underfloor pipe's stripe).
pub fn floor_temp_k(x: f64) -> f64 {
    291.0 + FLOOR_PIPE_PEAK_K * (-((x - FLOOR_PIPE_X) / FLOOR_PIPE_SIGMA).powi(2)).exp()
}
/// Wall layout: the wall is the plane y = `WALL_Y`, metres.
pub const WALL_Y: f64 = 0.0;
/// Wall layout: the wall's extent along x, metres.
pub const WALL_X: (f64, f64) = (-3.0, 3.0);
/// Wall layout: the wall's extent along z, metres.
pub const WALL_Z: (f64, f64) = (0.0, 3.0);
/// Wall layout: temperature of the wall away from the pipe, kelvin.
pub const WALL_BASE_K: f64 = 280.0;
/// Wall layout: the emissivity edge is the vertical line x = `WALL_EDGE_X` (painted for x below).
pub const WALL_EDGE_X: f64 = 0.0;
/// Wall layout: emissivity of the painted part.
pub const WALL_PAINT_EMISSIVITY: f64 = 0.95;
/// Wall layout: emissivity of the bare-metal part.
pub const WALL_METAL_EMISSIVITY: f64 = 0.12;
/// Wall layout: height of the in-wall pipe's axis (the warm band's centre line), metres.
pub const WALL_PIPE_Z: f64 = 0.75;
/// Wall layout: width parameter σ of the warm band across the pipe, metres.
pub const WALL_PIPE_SIGMA: f64 = 0.2;
/// Wall layout: peak warming of the wall surface above the pipe, kelvin.
pub const WALL_PIPE_PEAK_K: f64 = 12.0;
/// Wall layout: where along x the pipe is hottest, metres.
pub const WALL_PIPE_HOT_X: f64 = -0.6;
/// Wall layout: length scale of the band's slow cooling along x, metres.
pub const WALL_PIPE_LENGTH: f64 = 1.0;

/// Wall surface temperature at `(x, z)`: [`WALL_BASE_K`] plus the in-wall pipe's warm band.
pub fn wall_temp_k(x: f64, z: f64) -> f64 {
    let across = (z - WALL_PIPE_Z) / WALL_PIPE_SIGMA;
    let along = (x - WALL_PIPE_HOT_X) / WALL_PIPE_LENGTH;
    WALL_BASE_K + WALL_PIPE_PEAK_K * (-across * across - along * along).exp()
}

/// Wall layout: emissivity and RGB albedo at `x`.
fn wall_material(x: f64) -> (f64, [f64; 3]) {
    if x < WALL_EDGE_X {
        (WALL_PAINT_EMISSIVITY, [0.30, 0.38, 0.55])
    } else {
        (WALL_METAL_EMISSIVITY, [0.62, 0.62, 0.64])
    }
}

// The radiator stands off the pipe's hot end (plane x = RAD_X, facing +x), clear of the lines
// of sight of the views from ±y that see the pipe side-on.
pub(crate) const RAD_X: f64 = -0.9;
pub(crate) const RAD_Y: (f64, f64) = (-0.45, 0.45);
pub(crate) const RAD_Z: (f64, f64) = (0.05, 0.65);

pub(super) fn pipe_temp_k(x: f64) -> f64 {
    let f = ((x - PIPE_X.0) / (PIPE_X.1 - PIPE_X.0)).clamp(0.0, 1.0);
    333.0 - 30.0 * f
}

fn radiator_temp_k(y: f64) -> f64 {
    318.0 + 4.0 * (2.0 * std::f64::consts::PI * y / 0.06).cos()
}

/// A deterministic value in [0, 1) for the lattice point `(x, y, z)` and `seed`: the
/// simulator's one integer hash (the room's value noise, the facade's bricks and labels).
pub(crate) fn lattice_hash(x: i64, y: i64, z: i64, seed: u64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ seed;
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// `n` turned to face a ray of direction `d`.
pub(crate) fn face(n: DVec3, d: DVec3) -> DVec3 {
    if n.dot(d) > 0.0 { -n } else { n }
}

/// Nearest hit offered so far: the tracers' one closest-hit rule (`t > 1e-9`; on a tie the
/// first offered stays).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Nearest(pub(crate) Option<SurfaceHit>);

impl Nearest {
    pub(crate) fn offer(&mut self, h: SurfaceHit) {
        if h.t > 1e-9 && self.0.is_none_or(|b| h.t < b.t) {
            self.0 = Some(h);
        }
    }
}

/// Where the ray `o + t d` meets the plane `p[axis] = at`: `(t, p)`; `None` when it runs
/// parallel to the plane (|d[axis]| ≤ 1e-12).
pub(crate) fn axis_plane(o: DVec3, d: DVec3, axis: usize, at: f64) -> Option<(f64, DVec3)> {
    if d[axis].abs() <= 1e-12 {
        return None;
    }
    let t = (at - o[axis]) / d[axis];
    Some((t, o + d * t))
}

/// Nearest surface of `layout` along the ray `o + t d` (t > 1e-9), world frame.
pub fn trace(layout: SceneLayout, o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    match layout {
        SceneLayout::Objects => trace_objects(o, d),
        SceneLayout::Wall => trace_wall(o, d),
        SceneLayout::Facade => facade::trace_facade(o, d),
    }
}

fn trace_wall(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let (t, p) = axis_plane(o, d, 1, WALL_Y)?;
    let inside = p.x >= WALL_X.0 && p.x <= WALL_X.1 && p.z >= WALL_Z.0 && p.z <= WALL_Z.1;
    (t > 1e-9 && inside).then(|| {
        let (emissivity, albedo) = wall_material(p.x);
        SurfaceHit {
            t,
            temp_k: wall_temp_k(p.x, p.z),
            emissivity,
            albedo,
            normal: face(DVec3::Y, d),
            object: SceneObject::Wall,
        }
    })
}

fn trace_objects(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let mut nearest = Nearest::default();
    for hit in [ground(o, d), pipe_side(o, d)].into_iter().flatten() {
        nearest.offer(hit);
    }
    for x in [PIPE_X.0, PIPE_X.1] {
        if let Some(hit) = pipe_cap(o, d, x) {
            nearest.offer(hit);
        }
    }
    for hit in [box_face(o, d), radiator(o, d)].into_iter().flatten() {
        nearest.offer(hit);
    }
    nearest.0
}

/// The ground (z = 0 within ±2 m), tiled.
fn ground(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let (t, p) = axis_plane(o, d, 2, 0.0)?;
    (p.x.abs() <= 2.0 && p.y.abs() <= 2.0).then(|| {
        let tile = ((p.x / 0.2).floor() + (p.y / 0.2).floor()) as i64 % 2 == 0;
        let a = if tile { 0.30 } else { 0.38 };
        SurfaceHit {
            t,
            temp_k: floor_temp_k(p.x),
            emissivity: 0.95,
            albedo: [a, a * 0.95, a * 0.85],
            normal: face(DVec3::Z, d),
            object: SceneObject::Ground,
        }
    })
}

/// The pipe's cylindrical side (its nearer crossing within the pipe's length).
fn pipe_side(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let (oy, oz) = (o.y - PIPE_YZ.0, o.z - PIPE_YZ.1);
    let a = d.y * d.y + d.z * d.z;
    if a <= 1e-15 {
        return None;
    }
    let b = 2.0 * (oy * d.y + oz * d.z);
    let c = oy * oy + oz * oz - PIPE_R * PIPE_R;
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    [
        (-b - disc.sqrt()) / (2.0 * a),
        (-b + disc.sqrt()) / (2.0 * a),
    ]
    .into_iter()
    .find_map(|t| {
        let p = o + d * t;
        (t > 1e-9 && p.x >= PIPE_X.0 && p.x <= PIPE_X.1).then(|| {
            let n = DVec3::new(0.0, p.y - PIPE_YZ.0, p.z - PIPE_YZ.1) / PIPE_R;
            SurfaceHit {
                t,
                temp_k: pipe_temp_k(p.x),
                emissivity: 0.9,
                albedo: [0.55, 0.25, 0.12],
                normal: face(n, d),
                object: SceneObject::PipeSide,
            }
        })
    })
}

/// The pipe's end cap at `x`.
fn pipe_cap(o: DVec3, d: DVec3, x: f64) -> Option<SurfaceHit> {
    let (t, p) = axis_plane(o, d, 0, x)?;
    ((p.y - PIPE_YZ.0).powi(2) + (p.z - PIPE_YZ.1).powi(2) <= PIPE_R * PIPE_R).then(|| SurfaceHit {
        t,
        temp_k: pipe_temp_k(x),
        emissivity: 0.9,
        albedo: [0.45, 0.2, 0.1],
        normal: face(DVec3::X, d),
        object: SceneObject::PipeCap,
    })
}

/// The box (slab test), painted on its x < `BOX_C.x` half.
fn box_face(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let lo = BOX_C - DVec3::splat(BOX_H);
    let hi = BOX_C + DVec3::splat(BOX_H);
    let (mut t0, mut t1, mut axis0) = (f64::MIN, f64::MAX, 0usize);
    for k in 0..3 {
        let (ok, dk, lk, hk) = (o[k], d[k], lo[k], hi[k]);
        if dk.abs() < 1e-15 {
            if ok < lk || ok > hk {
                return None;
            }
            continue;
        }
        let (mut a, mut b) = ((lk - ok) / dk, (hk - ok) / dk);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t0 {
            t0 = a;
            axis0 = k;
        }
        t1 = t1.min(b);
    }
    if !(t0 <= t1 && t0 > 1e-9) {
        return None;
    }
    let p = o + d * t0;
    let mut n = DVec3::ZERO;
    n[axis0] = 1.0;
    let painted = p.x < BOX_C.x;
    Some(SurfaceHit {
        t: t0,
        temp_k: 313.0,
        emissivity: if painted { 0.95 } else { 0.12 },
        albedo: if painted {
            [0.15, 0.25, 0.6]
        } else {
            [0.6, 0.6, 0.62]
        },
        normal: face(n, d),
        object: SceneObject::Box,
    })
}

/// The radiator panel (double-sided, its fins as a cosine).
fn radiator(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let (t, p) = axis_plane(o, d, 0, RAD_X)?;
    (p.y >= RAD_Y.0 && p.y <= RAD_Y.1 && p.z >= RAD_Z.0 && p.z <= RAD_Z.1).then(|| {
        let fin = 0.75 + 0.1 * (2.0 * std::f64::consts::PI * p.y / 0.06).cos();
        SurfaceHit {
            t,
            temp_k: radiator_temp_k(p.y),
            emissivity: 0.93,
            albedo: [fin, fin, fin * 0.97],
            normal: face(DVec3::X, d),
            object: SceneObject::Radiator,
        }
    })
}

fn albedo_to_srgb8(a: [f64; 3]) -> [u8; 3] {
    a.map(|c| (crate::sensor::srgb_encode(c) * 255.0).round() as u8)
}

/// `count` points sampled on the surfaces of `layout` (Objects: the objects and the near
/// ground; Wall and Facade: the part of the wall the cameras see, x ∈ ±1.5 m,
/// z ∈ [0.1, 1.8] m), with colour.
pub fn sample_surface_points(
    layout: SceneLayout,
    count: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<(DVec3, [u8; 3])> {
    match layout {
        SceneLayout::Objects => sample_object_points(count, rng),
        SceneLayout::Facade => (0..count)
            .map(|_| {
                let x = rng.random_range(-1.5..1.5);
                let z = rng.random_range(0.1..1.8);
                let albedo = facade::facade_material(x, z).2;
                (DVec3::new(x, WALL_Y, z), albedo_to_srgb8(albedo))
            })
            .collect(),
        SceneLayout::Wall => (0..count)
            .map(|_| {
                let x = rng.random_range(-1.5..1.5);
                let z = rng.random_range(0.1..1.8);
                (
                    DVec3::new(x, WALL_Y, z),
                    albedo_to_srgb8(wall_material(x).1),
                )
            })
            .collect(),
    }
}

fn sample_object_points(count: usize, rng: &mut ChaCha8Rng) -> Vec<(DVec3, [u8; 3])> {
    let mut pts = Vec::with_capacity(count);
    let to8 = albedo_to_srgb8;
    while pts.len() < count {
        let kind = rng.random_range(0..4);
        let (p, albedo) = match kind {
            0 => {
                let p = DVec3::new(
                    rng.random_range(-1.2..1.2),
                    rng.random_range(-1.2..1.2),
                    0.0,
                );
                let h = trace_objects(p + DVec3::Z * 1e-3, DVec3::NEG_Z);
                (p, h.map_or([0.3; 3], |h| h.albedo))
            }
            1 => {
                let x = rng.random_range(PIPE_X.0..PIPE_X.1);
                let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                (
                    DVec3::new(
                        x,
                        PIPE_YZ.0 + PIPE_R * a.cos(),
                        PIPE_YZ.1 + PIPE_R * a.sin(),
                    ),
                    [0.55, 0.25, 0.12],
                )
            }
            2 => {
                // A point on one of the five visible box faces (not the bottom).
                let f = rng.random_range(0..5usize);
                let (s, t): (f64, f64) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                let local = match f {
                    0 => DVec3::new(1.0, s, t),
                    1 => DVec3::new(-1.0, s, t),
                    2 => DVec3::new(s, 1.0, t),
                    3 => DVec3::new(s, -1.0, t),
                    _ => DVec3::new(s, t, 1.0),
                };
                let p = BOX_C + local * BOX_H;
                (
                    p,
                    if p.x < BOX_C.x {
                        [0.15, 0.25, 0.6]
                    } else {
                        [0.6, 0.6, 0.62]
                    },
                )
            }
            _ => {
                let p = DVec3::new(
                    RAD_X,
                    rng.random_range(RAD_Y.0..RAD_Y.1),
                    rng.random_range(RAD_Z.0..RAD_Z.1),
                );
                (p, [0.75; 3])
            }
        };
        pts.push((p, to8(albedo)));
    }
    pts
}
