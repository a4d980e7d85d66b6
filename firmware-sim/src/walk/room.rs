//! The room the walk goes through: the `objects` scene inside floor and walls, the surfaces'
//! albedo texture ([`texture`]), the calibration board standing in it ([`walk_board_pose`]),
//! its AprilTags ([`walk_tags`]) and the tracer that sees all of it ([`trace_walk`]).

use glam::{DMat3, DQuat, DVec3};
use s3tir_calib::Rigid3;

use super::fiducials::{PrintedTag, TagInk, room_tags, tag_albedo};
use super::{ROOM_HALF_M, ROOM_HEIGHT_M};
use crate::scene::objects::{Nearest, axis_plane, lattice_hash};
use crate::scene::{self, SceneLayout, SurfaceHit};

/// Temperature of the room's walls, kelvin.
pub const ROOM_WALL_K: f64 = 290.0;

/// 3-D value noise in [0, 1] (smooth, trilinear between hashed lattice values).
fn value_noise(p: DVec3, seed: u64) -> f64 {
    let hash = |x: i64, y: i64, z: i64| lattice_hash(x, y, z, seed);
    let f = p.floor();
    let (x0, y0, z0) = (f.x as i64, f.y as i64, f.z as i64);
    let t = p - f;
    let sm = |v: f64| v * v * (3.0 - 2.0 * v);
    let (u, v, w) = (sm(t.x), sm(t.y), sm(t.z));
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let c = |dx, dy, dz| hash(x0 + dx, y0 + dy, z0 + dz);
    lerp(
        lerp(
            lerp(c(0, 0, 0), c(1, 0, 0), u),
            lerp(c(0, 1, 0), c(1, 1, 0), u),
            v,
        ),
        lerp(
            lerp(c(0, 0, 1), c(1, 0, 1), u),
            lerp(c(0, 1, 1), c(1, 1, 1), u),
            v,
        ),
        w,
    )
}

/// The walk scene's albedo at world point `p` on a surface of colour `base`: multi-scale
/// value noise (3, 7, 17, 40 cycles per metre) with a contrast curve, and a second noise field
/// that tints it, so that no two patches look alike.
pub fn texture(p: DVec3, base: [f64; 3]) -> [f64; 3] {
    let mut n = 0.0;
    for (freq, amp, seed) in [
        (3.0, 0.35, 11u64),
        (7.0, 0.3, 23),
        (17.0, 0.22, 37),
        (40.0, 0.13, 51),
    ] {
        n += amp * value_noise(p * freq, seed);
    }
    let n = ((n - 0.5) * 2.2 + 0.5).clamp(0.0, 1.0);
    let tint = value_noise(p * 2.0 + DVec3::splat(17.3), 77);
    let shade = 0.25 + 1.5 * n;
    [
        (base[0] * shade * (0.75 + 0.5 * tint)).clamp(0.0, 1.0),
        (base[1] * shade).clamp(0.0, 1.0),
        (base[2] * shade * (1.25 - 0.5 * tint)).clamp(0.0, 1.0),
    ]
}

/// What the walk room holds besides the scene (module docs): how its tags are made, and
/// whether the calibration board stands in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WalkRoom {
    pub tags: TagInk,
    pub board: bool,
}

/// The calibration board standing in the walk room (`run --walk-board`): the simulator's
/// emissivity board ([`crate::board::BoardSpec::default`], 9 × 6 squares of 60 mm), its
/// bottom edge on the floor, leaning back [`WALK_BOARD_LEAN_DEG`], its centre
/// [`WALK_BOARD_RADIUS_M`] from the scene's axis at azimuth [`WALK_BOARD_AZIMUTH_DEG`] and
/// facing out, so that the walk sees it over about half a lap; warmed to [`WALK_BOARD_K`] (the
/// room is 290 K), so its coated squares look darker than its paper in thermal, as on a
/// sunlit board.
pub const WALK_BOARD_AZIMUTH_DEG: f64 = -120.0;
pub const WALK_BOARD_RADIUS_M: f64 = 0.85;
pub const WALK_BOARD_LEAN_DEG: f64 = 15.0;
pub const WALK_BOARD_K: f64 = 305.0;

/// `world_from_board` of the walk room's board: board x along the floor (to the right as
/// seen from outside), board y down its face, board z into it (the board frame of
/// `board.toml`, corner (0, 0) at the origin).
pub fn walk_board_pose() -> Rigid3 {
    let b = crate::board::BoardSpec::default();
    let (x0, y0, x1, y1) = b.extent_m();
    let az = WALK_BOARD_AZIMUTH_DEG.to_radians();
    let out = DVec3::new(az.cos(), az.sin(), 0.0);
    let right = DVec3::Z.cross(out); // along the floor, to the right seen from outside
    let lean = WALK_BOARD_LEAN_DEG.to_radians();
    // Up the face (leaning back, away from the viewer outside) and the face's normal.
    let up = DVec3::Z * lean.cos() - out * lean.sin();
    let normal_out = right.cross(up);
    // Board axes in the world: x = right, y = −up (down the face), z = −normal_out.
    let rot = DMat3::from_cols(right, -up, -normal_out);
    let height = y1 - y0;
    let bottom_centre = out * WALK_BOARD_RADIUS_M;
    let top_left = bottom_centre + up * height - right * (0.5 * (x1 - x0));
    // World position of the board origin: the top-left extent corner is at (x0, y0).
    let origin = top_left - rot * DVec3::new(x0, y0, 0.0);
    Rigid3::new(DQuat::from_mat3(&rot), origin)
}

/// The board along `o + t d`: `(t, board point, normal facing the ray, front)` when the ray
/// meets it; `front` when it meets the printed face (board z points into the face).
fn hit_walk_board(o: DVec3, d: DVec3) -> Option<(f64, DVec3, DVec3, bool)> {
    static POSE: std::sync::OnceLock<(Rigid3, Rigid3)> = std::sync::OnceLock::new();
    let (world_from_board, board_from_world) = POSE.get_or_init(|| {
        let p = walk_board_pose();
        (p, p.inverse())
    });
    let (ob, db) = (
        board_from_world.transform_point(o),
        board_from_world.transform_vector(d),
    );
    if db.z.abs() <= 1e-12 {
        return None;
    }
    let t = -ob.z / db.z;
    let p = ob + db * t;
    let (x0, y0, x1, y1) = crate::board::BoardSpec::default().extent_m();
    (t > 1e-9 && p.x >= x0 && p.x < x1 && p.y >= y0 && p.y < y1).then(|| {
        let n = world_from_board.transform_vector(DVec3::NEG_Z);
        (t, p, if n.dot(d) < 0.0 { n } else { -n }, db.z > 0.0)
    })
}

/// Nearest surface of the walk scene along `o + t d` (module docs), with its texture, in the
/// room `room` (its tags' make, its board).
pub fn trace_walk(o: DVec3, d: DVec3, room: WalkRoom) -> Option<SurfaceHit> {
    let ink = room.tags;
    let best = scene::trace(SceneLayout::Objects, o, d);
    if room.board
        && let Some((t, p, normal, front)) = hit_walk_board(o, d)
        && best.is_none_or(|b| t < b.t)
    {
        let b = crate::board::BoardSpec::default();
        if let Some(m) = b.material_at(p.x, p.y) {
            // The back is plain: grey paint (ε 0.95) at the board's temperature.
            let (emissivity, albedo) = if front {
                (b.emissivity(m), b.reflectance(m))
            } else {
                (0.95, 0.5)
            };
            return Some(SurfaceHit {
                t,
                temp_k: WALK_BOARD_K,
                emissivity,
                albedo: [albedo; 3],
                normal,
                object: scene::SceneObject::Wall,
            });
        }
    }
    let mut nearest = Nearest(best);
    // The floor beyond the objects layout's ±2 m.
    if let Some((t, p)) = axis_plane(o, d, 2, 0.0) {
        let outer = p.x.abs().max(p.y.abs());
        if outer > 2.0 && outer <= ROOM_HALF_M {
            nearest.offer(SurfaceHit {
                t,
                temp_k: scene::floor_temp_k(p.x),
                emissivity: 0.95,
                albedo: [0.34, 0.32, 0.29],
                normal: if d.z > 0.0 { DVec3::NEG_Z } else { DVec3::Z },
                object: scene::SceneObject::Ground,
            });
        }
    }
    // Walls x = ±ROOM_HALF_M and y = ±ROOM_HALF_M.
    for axis in [0usize, 1] {
        for side in [-1.0, 1.0] {
            let Some((t, p)) = axis_plane(o, d, axis, side * ROOM_HALF_M) else {
                continue;
            };
            let other = p[1 - axis];
            if other.abs() <= ROOM_HALF_M && p.z >= 0.0 && p.z <= ROOM_HEIGHT_M {
                let mut n = DVec3::ZERO;
                n[axis] = -side;
                let base = if axis == 0 {
                    [0.55, 0.5, 0.42]
                } else {
                    [0.42, 0.5, 0.55]
                };
                nearest.offer(SurfaceHit {
                    t,
                    temp_k: ROOM_WALL_K + 0.5 * (p.z - 1.0),
                    emissivity: 0.9,
                    albedo: base,
                    normal: n,
                    object: scene::SceneObject::Wall,
                });
            }
        }
    }
    nearest.0.map(|mut h| {
        let p = o + d * h.t;
        h.albedo = match h.object {
            scene::SceneObject::Wall | scene::SceneObject::Ground => {
                match tag_albedo(walk_tags(), p) {
                    Some(a) => {
                        if let Some((temp_k, emissivity)) = ink.thermal(a) {
                            h.temp_k = temp_k;
                            h.emissivity = emissivity;
                        }
                        [a; 3]
                    }
                    None => texture(p, h.albedo),
                }
            }
            _ => texture(p, h.albedo),
        };
        h
    })
}

/// The room's AprilTags ([`super::fiducials`]), built once.
pub fn walk_tags() -> &'static [PrintedTag] {
    static TAGS: std::sync::OnceLock<Vec<PrintedTag>> = std::sync::OnceLock::new();
    TAGS.get_or_init(room_tags)
}

/// The scene's centre and the diameter of its bounding sphere (the room), metres.
pub fn scene_extent() -> (DVec3, f64) {
    let c = DVec3::new(0.0, 0.0, ROOM_HEIGHT_M / 2.0);
    let corner = DVec3::new(ROOM_HALF_M, ROOM_HALF_M, ROOM_HEIGHT_M / 2.0);
    (c, 2.0 * corner.length())
}
