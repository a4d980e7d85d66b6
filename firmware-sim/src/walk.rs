//! `run --walk`: the rig moves through a scene, and both cameras see it move.
//!
//! **Scene** ([`trace_walk`]): the `objects` layout of [`crate::scene`] (heated pipe, box with an
//! emissivity edge, floor with an underfloor pipe, finned radiator; its thermal field
//! unchanged) inside a room: the floor extended to ±[`ROOM_HALF_M`] and four walls
//! [`ROOM_HEIGHT_M`] high at 290 K (ε 0.9, thermally bland). Every surface carries a seeded,
//! non-repeating, multi-scale albedo texture ([`texture`]: value noise at 3–40 cycles per metre
//! times the surface's colour) that feature matchers can use; the thermal images do not see it.
//! AprilTags are printed low on the walls and on the floor ([`crate::fiducials`]; RGB only, or
//! thermal too when made as heated tags: [`TagInk`]). With `--walk-board` the emissivity board
//! stands in the room ([`walk_board_pose`]): the poses stage's `--board`.
//!
//! **Trajectories** ([`world_from_thermal`], the rig frame is the thermal camera):
//! - `orbit`: a circle of radius 1.7 m at 1.0 m height around (0, 0, 0.2), looking at it,
//!   0.25 rad/s (≈ 14° per second);
//! - `handheld`: a person walking the same way around: radius 1.7 ± 0.12 m and height
//!   1.0 ± 0.06 m drifting slowly, a 1.7 Hz step bob of 1.5 cm, the angular speed varying by
//!   ± 0.03 rad/s, the aim wandering ± 8 cm around the target, ± 2° of roll and a 3 Hz hand
//!   tremor of ± 0.3°; all smooth (sums of sines), the phases drawn from the seed.
//!
//! **Frames**: the thermal core at its profile's rate, the RGB camera at [`WALK_RGB_HZ`]
//! (640×360 binned by default). Frame k of a stream is exposed at `k / rate` seconds of sensor
//! time, rendered at the poses of its exposure (motion blur: the thermal core integrates
//! 2 instants over 12 ms with 2×2 sub-pixels, the RGB camera 3 instants over 16 ms, one jittered
//! ray per pixel each), then goes through the same sensor models as every simulated frame
//! (thermal: PSF, NETD noise, fixed pattern, FFC freezes, telemetry; RGB: PSF, shot and read
//! noise, sRGB, MJPEG). One FFC is requested at 40 % of the walk. Rendering does not keep up
//! with real time on a small machine: frames are sent when ready (never before their due
//! time), stamped at their exposure on the walk's clock, so the recorded content never depends
//! on the machine's speed.
//!
//! **Truth** (`--truth-dir DIR`): `DIR/truth.json` (format `s3tir-walk-truth/1`, written
//! atomically when the walk ends): both camera models, `rgb_from_thermal`, the scene's centre
//! and extent, and every frame sent with its stream, sequence, `monotonic_ns` (exactly the
//! stamp on the wire) and `world_from_cam` at that instant; `DIR/tags.toml` maps the room's
//! AprilTags (the poses stage's `--tags FILE`); with the board, `DIR/board.toml` and its
//! `world_from_board` in `truth.json` (`board`).

use std::io::Write as _;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use glam::{DMat3, DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use s3tir_calib::{CameraModel, Rigid3};
use s3tir_capture::device::FourCc;
use s3tir_capture::frame::ThermalUnits;
use s3tir_capture::simwire::{self, StreamId, WireFrame};
use serde::Serialize;

use crate::dataset::PoseJson;
use crate::error::SimError;
use crate::fiducials::TagInk;
use crate::physics::Radiometry;
use crate::render::{RayGrid, gaussian_blur};
use crate::rig::Rig;
use crate::scene::{self, BACKGROUND_K, ENV_K, SceneLayout, SurfaceHit};
use crate::sensor::{RgbProfile, ThermalOutput, ThermalProfile, ThermalSensor, rgb_to_jpeg};
use crate::serve::monotonic_ns;

/// Half-size of the room around the scene (floor and walls), metres.
pub const ROOM_HALF_M: f64 = 3.0;
/// Height of the room's walls, metres.
pub const ROOM_HEIGHT_M: f64 = 2.5;
/// Temperature of the room's walls, kelvin.
pub const ROOM_WALL_K: f64 = 290.0;
/// The point every walk looks at, metres.
pub const WALK_TARGET: DVec3 = DVec3::new(0.0, 0.0, 0.2);
/// RGB frame rate during a walk.
pub const WALK_RGB_HZ: f64 = 10.0;
/// Radius of the walk around [`WALK_TARGET`], metres.
pub const WALK_RADIUS_M: f64 = 1.7;
/// Mean angular speed around the scene, rad/s.
pub const WALK_RATE_RAD_S: f64 = 0.25;

/// Which path the rig walks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WalkKind {
    Orbit,
    Handheld,
    /// The rig stands still and a person waves the emissivity board in front of it: the board
    /// set's poses ([`crate::rig::plan_board_views`]), each held [`BOARD_HOLD_S`], the board's
    /// heat model running from 60 s after the temperature step (`cooled`). A calibration
    /// session (`s3tir-calib SESSION --board board.toml`).
    Board,
}

impl WalkKind {
    pub fn name(self) -> &'static str {
        match self {
            WalkKind::Orbit => "orbit",
            WalkKind::Handheld => "handheld",
            WalkKind::Board => "board",
        }
    }
}

/// How long the waved board holds each pose, seconds.
pub const BOARD_HOLD_S: f64 = 1.0;

/// A walk: its path, length and seed, and where its truth goes.
#[derive(Debug, Clone)]
pub struct WalkSpec {
    pub kind: WalkKind,
    pub duration_s: f64,
    pub truth_dir: Option<PathBuf>,
    /// What the room holds besides the scene: its tags' make, the board ([`WalkRoom`]).
    pub room: WalkRoom,
}

/// Seeded phases of the hand-held path's sines.
#[derive(Debug, Clone, Copy)]
pub struct WalkPath {
    pub kind: WalkKind,
    phases: [f64; 12],
}

impl WalkPath {
    pub fn new(kind: WalkKind, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x3A1C_0DE5);
        let mut phases = [0.0; 12];
        for p in &mut phases {
            *p = rng.random_range(0.0..std::f64::consts::TAU);
        }
        Self { kind, phases }
    }

    /// The rig's (thermal camera's) pose at `t_s` seconds into the walk.
    pub fn world_from_thermal(&self, t_s: f64) -> Rigid3 {
        world_from_thermal(self, t_s)
    }
}

/// The rig's pose at `t_s` (module docs).
pub fn world_from_thermal(path: &WalkPath, t_s: f64) -> Rigid3 {
    let p = &path.phases;
    let s = |f: f64, k: usize| (f * t_s + p[k]).sin();
    let (radius, height, angle, aim, roll, tremor) = match path.kind {
        // The board wave's world is the board frame: see `run_board_wave`.
        WalkKind::Board => return Rigid3::IDENTITY,
        WalkKind::Orbit => (
            WALK_RADIUS_M,
            1.0,
            WALK_RATE_RAD_S * t_s,
            WALK_TARGET,
            0.0,
            DVec3::ZERO,
        ),
        WalkKind::Handheld => {
            // ∫ (ω + 0.03 sin(0.4 t + φ)) dt
            let angle =
                WALK_RATE_RAD_S * t_s - 0.03 / 0.4 * ((0.4 * t_s + p[0]).cos() - p[0].cos());
            (
                WALK_RADIUS_M + 0.12 * s(0.5, 1),
                1.0 + 0.06 * s(0.9, 2) + 0.015 * s(std::f64::consts::TAU * 1.7, 3),
                angle,
                WALK_TARGET + DVec3::new(0.08 * s(0.7, 4), 0.08 * s(0.6, 5), 0.04 * s(0.8, 6)),
                2f64.to_radians() * s(1.1, 7),
                DVec3::new(
                    0.3f64.to_radians() * s(std::f64::consts::TAU * 3.0, 8),
                    0.3f64.to_radians() * s(std::f64::consts::TAU * 2.7, 9),
                    0.0,
                ),
            )
        }
    };
    let a = std::f64::consts::FRAC_PI_2 + angle;
    let eye = DVec3::new(radius * a.cos(), radius * a.sin(), height);
    let fwd = (aim - eye).normalize();
    let right = fwd.cross(DVec3::Z).normalize();
    let down = fwd.cross(right);
    let base = DQuat::from_mat3(&DMat3::from_cols(right, down, fwd));
    // Roll about the optical axis, tremor about the camera's x and y (camera frame).
    let local = DQuat::from_rotation_z(roll)
        * DQuat::from_rotation_x(tremor.x)
        * DQuat::from_rotation_y(tremor.y);
    Rigid3::new(base * local, eye)
}

/// 3-D value noise in [0, 1] (smooth, trilinear between hashed lattice values).
fn value_noise(p: DVec3, seed: u64) -> f64 {
    let hash = |x: i64, y: i64, z: i64| -> f64 {
        let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
            ^ seed;
        h ^= h >> 33;
        h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
        h ^= h >> 33;
        (h >> 11) as f64 / (1u64 << 53) as f64
    };
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
    let mut best = scene::trace(SceneLayout::Objects, o, d);
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
    let mut consider = |h: SurfaceHit| {
        if h.t > 1e-9 && best.is_none_or(|b| h.t < b.t) {
            best = Some(h);
        }
    };
    // The floor beyond the objects layout's ±2 m.
    if d.z.abs() > 1e-12 {
        let t = -o.z / d.z;
        let p = o + d * t;
        let outer = p.x.abs().max(p.y.abs());
        if outer > 2.0 && outer <= ROOM_HALF_M {
            consider(SurfaceHit {
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
        if d[axis].abs() <= 1e-12 {
            continue;
        }
        for side in [-1.0, 1.0] {
            let t = (side * ROOM_HALF_M - o[axis]) / d[axis];
            let p = o + d * t;
            let other = p[1 - axis];
            if other.abs() <= ROOM_HALF_M && p.z >= 0.0 && p.z <= ROOM_HEIGHT_M {
                let mut n = DVec3::ZERO;
                n[axis] = -side;
                let base = if axis == 0 {
                    [0.55, 0.5, 0.42]
                } else {
                    [0.42, 0.5, 0.55]
                };
                consider(SurfaceHit {
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
    best.map(|mut h| {
        let p = o + d * h.t;
        h.albedo = match h.object {
            scene::SceneObject::Wall | scene::SceneObject::Ground => {
                match crate::fiducials::tag_albedo(walk_tags(), p) {
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

/// The room's AprilTags ([`crate::fiducials`]), built once.
pub fn walk_tags() -> &'static [crate::fiducials::PrintedTag] {
    static TAGS: std::sync::OnceLock<Vec<crate::fiducials::PrintedTag>> =
        std::sync::OnceLock::new();
    TAGS.get_or_init(crate::fiducials::room_tags)
}

/// The scene's centre and the diameter of its bounding sphere (the room), metres.
pub fn scene_extent() -> (DVec3, f64) {
    let c = DVec3::new(0.0, 0.0, ROOM_HEIGHT_M / 2.0);
    let corner = DVec3::new(ROOM_HALF_M, ROOM_HALF_M, ROOM_HEIGHT_M / 2.0);
    (c, 2.0 * corner.length())
}

/// Renders the thermal radiance of one frame: 2 instants over the exposure, 2×2 sub-pixels.
fn render_thermal(
    grid: &RayGrid,
    poses: &[Rigid3],
    radiometry: &Radiometry,
    room: WalkRoom,
) -> Vec<f64> {
    let (w, h) = (grid.width(), grid.height());
    let l_env = radiometry.radiance(ENV_K);
    let l_bg = radiometry.radiance(BACKGROUND_K);
    let mut out = vec![0.0; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, px) in row.iter_mut().enumerate() {
            let mut acc = 0.0;
            let mut n = 0.0;
            for (k, pose) in poses.iter().enumerate() {
                for j in 0..2 {
                    for i in 0..2 {
                        let (a, b) = (0.25 + 0.5 * i as f64, 0.25 + 0.5 * j as f64);
                        let a = (a + 0.125 * k as f64).fract();
                        let d = pose.transform_vector(grid.sub_ray(u, v, a, b));
                        acc += match trace_walk(pose.translation_m, d, room) {
                            Some(s) => {
                                s.emissivity * radiometry.radiance(s.temp_k)
                                    + (1.0 - s.emissivity) * l_env
                            }
                            None => l_bg,
                        };
                        n += 1.0;
                    }
                }
            }
            *px = acc / n;
        }
    });
    out
}

/// Renders the linear RGB of one frame: one jittered ray per pixel and instant.
fn render_rgb(grid: &RayGrid, poses: &[Rigid3], room: WalkRoom) -> [Vec<f64>; 3] {
    let (w, h) = (grid.width(), grid.height());
    let light = DVec3::new(0.3, -0.4, 1.0).normalize();
    let jitter = [(0.3, 0.4), (0.7, 0.6), (0.5, 0.2), (0.2, 0.8)];
    let mut rgb = vec![[0.0f64; 3]; w * h];
    rgb.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, px) in row.iter_mut().enumerate() {
            let mut c = [0.0; 3];
            for (k, pose) in poses.iter().enumerate() {
                let (a, b) = jitter[k % jitter.len()];
                let d = pose.transform_vector(grid.sub_ray(u, v, a, b));
                match trace_walk(pose.translation_m, d, room) {
                    Some(s) => {
                        let shade = 0.35 + 0.65 * s.normal.dot(light).max(0.0);
                        for (ch, a) in c.iter_mut().zip(s.albedo) {
                            *ch += a * shade;
                        }
                    }
                    None => {
                        for ch in &mut c {
                            *ch += 0.3;
                        }
                    }
                }
            }
            for ch in &mut c {
                *ch /= poses.len() as f64;
            }
            *px = c;
        }
    });
    [0, 1, 2].map(|k| rgb.iter().map(|p| p[k]).collect())
}

/// Exposure instants (seconds, relative to the frame's stamp) of each camera.
const THERMAL_INSTANTS_S: [f64; 2] = [-0.006, 0.006];
const RGB_INSTANTS_S: [f64; 3] = [-0.008, 0.0, 0.008];

/// One frame of the walk, planned.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Planned {
    t_s: f64,
    stream: StreamId,
    sequence: u32,
}

/// One frame in `truth.json`.
#[derive(Debug, Clone, Serialize)]
pub struct TruthFrame {
    pub stream: &'static str,
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub ffc_frozen: bool,
    pub world_from_cam: PoseJson,
}

impl TruthFrame {
    /// A frame as sent; `monotonic_ns` is set from the wire stamp once the walk has run.
    fn sent(stream: StreamId, sequence: u32, ffc_frozen: bool, world_from_cam: &Rigid3) -> Self {
        Self {
            stream: match stream {
                StreamId::Thermal => "thermal",
                StreamId::Rgb => "rgb",
            },
            sequence,
            monotonic_ns: 0,
            ffc_frozen,
            world_from_cam: PoseJson::from(world_from_cam),
        }
    }
}

#[derive(Debug, Serialize)]
struct SceneJson {
    layout: &'static str,
    centre_m: [f64; 3],
    extent_m: f64,
}

#[derive(Debug, Serialize)]
struct TruthJson<'a> {
    format: &'static str,
    trajectory: &'static str,
    /// How the room's tags are made (`printed`: RGB only; `heated`: thermal too).
    tags: &'static str,
    /// `world_from_board` of the board standing in the room (`--walk-board`; its
    /// `board.toml` beside the truth), or null.
    board: Option<PoseJson>,
    seed: u64,
    duration_s: f64,
    thermal_profile: &'static str,
    thermal: CameraModel,
    rgb: Option<CameraModel>,
    rgb_from_thermal: PoseJson,
    scene: SceneJson,
    frames: &'a [TruthFrame],
}

/// What the serving loop needs of the rig.
#[derive(Debug)]
pub struct WalkRig {
    pub thermal: ThermalProfile,
    pub rgb: Option<RgbProfile>,
    pub seed: u64,
}

/// Renders every frame of the walk in time order and hands each to `send` with its truth;
/// stops early when `stop` is set. Returns the truth of the frames sent.
pub fn run_walk(
    rig: &WalkRig,
    spec: &WalkSpec,
    stop: &AtomicBool,
    mut send: impl FnMut(WireFrame, f64) -> Result<(), SimError>,
) -> Result<Vec<TruthFrame>, SimError> {
    if spec.kind == WalkKind::Board {
        return run_board_wave(rig, spec, stop, send);
    }
    let path = WalkPath::new(spec.kind, rig.seed);
    let thermal = rig.thermal;
    let rgb_profile = rig.rgb;
    let rgb_from_thermal =
        Rig::new(thermal, rgb_profile.unwrap_or_else(RgbProfile::hd720)).rgb_from_thermal;
    let thermal_from_rgb = rgb_from_thermal.inverse();
    let plan = plan_frames(rig, spec.duration_s);

    let mut sensor = ThermalSensor::new(
        ThermalProfile {
            auto_ffc_period_s: 0.0,
            ..thermal
        },
        rig.seed,
    );
    let radiometry = Radiometry::new();
    let tgrid = RayGrid::new(&thermal.camera);
    let rgrid = rgb_profile.map(|p| RayGrid::new(&p.camera));
    let mut rgb_rng = ChaCha8Rng::seed_from_u64(rig.seed ^ 0x0C0F_FEE5);
    let ffc_at_s = 0.4 * spec.duration_s;
    let mut ffc_requested = false;
    let mut truth = Vec::with_capacity(plan.len());
    for item in plan {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let instants = |offsets: &[f64], from_thermal: Option<&Rigid3>| -> Vec<Rigid3> {
            offsets
                .iter()
                .map(|dt| {
                    let p = path.world_from_thermal((item.t_s + dt).max(0.0));
                    from_thermal.map_or(p, |t| p.compose(t))
                })
                .collect()
        };
        let (frame, world_from_cam, ffc_frozen) = match item.stream {
            StreamId::Thermal => {
                if !ffc_requested && item.t_s >= ffc_at_s {
                    sensor.request_ffc();
                    ffc_requested = true;
                }
                let poses = instants(&THERMAL_INSTANTS_S, None);
                let radiance = render_thermal(&tgrid, &poses, &radiometry, spec.room);
                let (w, h) = (
                    thermal.camera.width_px as usize,
                    thermal.camera.height_px as usize,
                );
                let blurred = gaussian_blur(&radiance, w, h, thermal.psf_sigma_px);
                let ThermalOutput::Frame(f) = sensor.next_frame(&blurred) else {
                    continue;
                };
                (
                    thermal_wire(&thermal, item.sequence, &f.words, f.ffc_frozen),
                    path.world_from_thermal(item.t_s),
                    f.ffc_frozen,
                )
            }
            StreamId::Rgb => {
                let (Some(p), Some(grid)) = (rgb_profile, rgrid.as_ref()) else {
                    continue;
                };
                let poses = instants(&RGB_INSTANTS_S, Some(&thermal_from_rgb));
                let lin = render_rgb(grid, &poses, spec.room);
                let (w, h) = (p.camera.width_px as usize, p.camera.height_px as usize);
                let blurred = lin.map(|c| gaussian_blur(&c, w, h, p.psf_sigma_px));
                let srgb = crate::sensor::expose_rgb_channels(
                    &p,
                    [&blurred[0], &blurred[1], &blurred[2]],
                    &mut rgb_rng,
                );
                let payload = rgb_to_jpeg(&srgb, p.camera.width_px, p.camera.height_px)?;
                (
                    rgb_wire(&p, item.sequence, payload),
                    path.world_from_thermal(item.t_s).compose(&thermal_from_rgb),
                    false,
                )
            }
        };
        let stream = frame.stream;
        let sequence = frame.sequence;
        send(frame, item.t_s)?;
        truth.push(TruthFrame::sent(
            stream,
            sequence,
            ffc_frozen,
            &world_from_cam,
        ));
    }
    Ok(truth)
}

/// The frame plan of a walk: every frame of both streams in time order.
fn plan_frames(rig: &WalkRig, duration_s: f64) -> Vec<Planned> {
    let thermal = rig.thermal;
    let mut plan: Vec<Planned> = Vec::new();
    let n_t = (duration_s * thermal.rate_hz).floor() as u32;
    plan.extend((0..n_t).map(|k| Planned {
        t_s: f64::from(k) / thermal.rate_hz,
        stream: StreamId::Thermal,
        sequence: k,
    }));
    if rig.rgb.is_some() {
        let n_r = (duration_s * WALK_RGB_HZ).floor() as u32;
        plan.extend((0..n_r).map(|k| Planned {
            t_s: f64::from(k) / WALK_RGB_HZ,
            stream: StreamId::Rgb,
            sequence: k,
        }));
    }
    plan.sort_by(|a, b| {
        a.t_s
            .total_cmp(&b.t_s)
            .then((a.stream as u8).cmp(&(b.stream as u8)))
    });
    plan
}

fn thermal_wire(profile: &ThermalProfile, sequence: u32, words: &[u16], frozen: bool) -> WireFrame {
    let mut flags = 0;
    if frozen {
        flags |= simwire::FLAG_FFC_FROZEN;
    }
    if profile.telemetry_rows > 0 {
        flags |= simwire::FLAG_TELEMETRY;
    }
    if profile.units == ThermalUnits::CentiKelvin {
        flags |= simwire::FLAG_TLINEAR;
    }
    WireFrame {
        stream: StreamId::Thermal,
        flags,
        fourcc: FourCc::Y16,
        width: profile.camera.width_px,
        height: profile.output_height(),
        bytes_per_line: profile.camera.width_px * 2,
        sequence,
        monotonic_ns: 0,
        payload: words.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

fn rgb_wire(profile: &RgbProfile, sequence: u32, payload: Vec<u8>) -> WireFrame {
    WireFrame {
        stream: StreamId::Rgb,
        flags: 0,
        fourcc: FourCc::MJPG,
        width: profile.camera.width_px,
        height: profile.camera.height_px,
        bytes_per_line: 0,
        sequence,
        monotonic_ns: 0,
        payload,
    }
}

/// [`WalkKind::Board`]: the rig still, the board waved through the board set's poses. The
/// truth's world frame is the board's (`world_from_cam = board_from_cam`).
fn run_board_wave(
    rig: &WalkRig,
    spec: &WalkSpec,
    stop: &AtomicBool,
    mut send: impl FnMut(WireFrame, f64) -> Result<(), SimError>,
) -> Result<Vec<TruthFrame>, SimError> {
    use crate::board::{BoardSpec, BoardThermal};
    use crate::rig::{plan_board_views, render_rgb_board, render_thermal_board};
    let board = BoardSpec::default();
    let rgb_profile = rig.rgb.unwrap_or_else(|| RgbProfile::hd720().binned2());
    let the_rig = Rig::new(rig.thermal, rgb_profile);
    let n_views = ((spec.duration_s / BOARD_HOLD_S).ceil() as usize).max(1);
    let views = plan_board_views(&the_rig, &board, n_views, rig.seed)?;
    let mut heat = BoardThermal::cooled(board);
    let first_view_s = 60.0;
    let mut sensor = ThermalSensor::new(
        ThermalProfile {
            auto_ffc_period_s: 0.0,
            ..rig.thermal
        },
        rig.seed,
    );
    let tgrid = RayGrid::new(&rig.thermal.camera);
    let rgrid = RayGrid::new(&rgb_profile.camera);
    let mut rgb_rng = ChaCha8Rng::seed_from_u64(rig.seed ^ 0x0052_4742);
    let thermal_from_rgb = the_rig.rgb_from_thermal.inverse();
    let ffc_at_s = 0.4 * spec.duration_s;
    let mut ffc_requested = false;
    let mut truth = Vec::new();
    for item in plan_frames(rig, spec.duration_s) {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let view = &views[((item.t_s / BOARD_HOLD_S) as usize).min(views.len() - 1)];
        let board_from_thermal = view.thermal_from_board.inverse();
        let (frame, world_from_cam, frozen) = match item.stream {
            StreamId::Thermal => {
                if !ffc_requested && item.t_s >= ffc_at_s {
                    sensor.request_ffc();
                    ffc_requested = true;
                }
                heat.advance(first_view_s + item.t_s - heat.time_s);
                let frozen = sensor.ffc_in_progress();
                let Some(words) =
                    render_thermal_board(&tgrid, &mut sensor, &heat, &view.thermal_from_board)
                else {
                    continue;
                };
                (
                    thermal_wire(&rig.thermal, item.sequence, &words, frozen),
                    board_from_thermal,
                    frozen,
                )
            }
            StreamId::Rgb => {
                let rgb_from_board = the_rig.rgb_from_thermal.compose(&view.thermal_from_board);
                let px =
                    render_rgb_board(&rgrid, &rgb_profile, &board, &rgb_from_board, &mut rgb_rng);
                let jpeg = rgb_to_jpeg(
                    &px,
                    rgb_profile.camera.width_px,
                    rgb_profile.camera.height_px,
                )?;
                (
                    rgb_wire(&rgb_profile, item.sequence, jpeg),
                    board_from_thermal.compose(&thermal_from_rgb),
                    false,
                )
            }
        };
        let stream = frame.stream;
        send(frame, item.t_s)?;
        truth.push(TruthFrame::sent(
            stream,
            item.sequence,
            frozen,
            &world_from_cam,
        ));
    }
    Ok(truth)
}

/// Writes `dir/truth.json` atomically (module docs).
pub fn write_truth(
    dir: &Path,
    rig: &WalkRig,
    spec: &WalkSpec,
    frames: &[TruthFrame],
) -> Result<(), SimError> {
    let io = |what: &'static str| {
        let path = dir.to_path_buf();
        move |source| SimError::Io { path, what, source }
    };
    std::fs::create_dir_all(dir).map_err(io("create truth folder"))?;
    let rgb_from_thermal =
        Rig::new(rig.thermal, rig.rgb.unwrap_or_else(RgbProfile::hd720)).rgb_from_thermal;
    let (centre, extent) = if spec.kind == WalkKind::Board {
        // The board wave: the scene is the board (its own frame); board.toml beside the truth.
        let b = crate::board::BoardSpec::default();
        let toml = crate::dataset::board_toml(&b, crate::dataset::Polarity::Cooled);
        std::fs::write(dir.join("board.toml"), toml).map_err(io("write board.toml"))?;
        let (x0, y0, x1, y1) = b.extent_m();
        (
            DVec3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0),
            ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt(),
        )
    } else {
        if spec.room.board {
            // The board in the room: the poses stage's --board file.
            let toml = crate::dataset::board_toml(
                &crate::board::BoardSpec::default(),
                // Warmer than its surroundings: coated squares look colder (`Cooled`'s look).
                crate::dataset::Polarity::Cooled,
            );
            std::fs::write(dir.join("board.toml"), toml).map_err(io("write board.toml"))?;
        }
        // The room's AprilTags: the poses stage's --tags map.
        std::fs::write(
            dir.join("tags.toml"),
            crate::fiducials::tags_toml(walk_tags()),
        )
        .map_err(io("write tags.toml"))?;
        scene_extent()
    };
    let doc = TruthJson {
        format: "s3tir-walk-truth/1",
        trajectory: spec.kind.name(),
        tags: spec.room.tags.name(),
        board: spec.room.board.then(|| PoseJson::from(&walk_board_pose())),
        seed: rig.seed,
        duration_s: spec.duration_s,
        thermal_profile: rig.thermal.name,
        thermal: rig.thermal.camera,
        rgb: rig.rgb.map(|p| p.camera),
        rgb_from_thermal: PoseJson::from(&rgb_from_thermal),
        scene: SceneJson {
            layout: if spec.kind == WalkKind::Board {
                "board"
            } else {
                "walk"
            },
            centre_m: centre.to_array(),
            extent_m: extent,
        },
        frames,
    };
    let text = serde_json::to_string_pretty(&doc).map_err(|e| SimError::Encode {
        what: "truth.json",
        reason: e.to_string(),
    })?;
    let tmp = dir.join("truth.json.tmp");
    std::fs::write(&tmp, text).map_err(io("write truth.json"))?;
    std::fs::rename(&tmp, dir.join("truth.json")).map_err(io("rename truth.json"))
}

/// Serves a walk on `socket`: announces `socket`, `thermal`, `rgb`, `walk` and `ready`, waits
/// for the first client, sends every frame (to every client connected by then), writes the
/// truth, announces `walk_done: thermal=N rgb=M`, then keeps the socket open until `stop`.
pub fn serve_walk(
    socket: &Path,
    rig: &WalkRig,
    spec: &WalkSpec,
    stop: Arc<AtomicBool>,
    announce: &mut dyn FnMut(&str, &str),
) -> Result<(), SimError> {
    let io = |what: &'static str| {
        let path = socket.to_path_buf();
        move |source| SimError::Io { path, what, source }
    };
    let _ = std::fs::remove_file(socket);
    let listener = UnixListener::bind(socket).map_err(io("bind socket"))?;
    listener
        .set_nonblocking(true)
        .map_err(io("set non-blocking"))?;
    announce("socket", &socket.display().to_string());
    announce(
        "thermal",
        &format!(
            "{} {}x{} Y16 {} Hz",
            rig.thermal.name,
            rig.thermal.camera.width_px,
            rig.thermal.camera.height_px,
            rig.thermal.rate_hz
        ),
    );
    if let Some(p) = rig.rgb {
        announce(
            "rgb",
            &format!(
                "{}x{} MJPG {WALK_RGB_HZ} Hz",
                p.camera.width_px, p.camera.height_px
            ),
        );
    }
    announce(
        "walk",
        &format!("{} {} s", spec.kind.name(), spec.duration_s),
    );
    announce("ready", "1");
    let mut clients: Vec<UnixStream> = Vec::new();
    let accept = |clients: &mut Vec<UnixStream>| {
        while let Ok((c, _)) = listener.accept() {
            let _ = c.set_nonblocking(false);
            clients.push(c);
        }
    };
    // Streaming starts with the first client, as V4L2 streaming starts on STREAMON.
    while clients.is_empty() {
        if stop.load(Ordering::Relaxed) {
            let _ = std::fs::remove_file(socket);
            return Ok(());
        }
        accept(&mut clients);
        std::thread::sleep(Duration::from_millis(5));
    }
    let start = Instant::now();
    let start_ns = monotonic_ns();
    let peer = socket.display().to_string();
    let mut stamps: Vec<u64> = Vec::new();
    let mut truth = run_walk(rig, spec, &stop, |mut frame, t_s| {
        accept(&mut clients);
        let due = start + Duration::from_secs_f64(t_s);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        frame.monotonic_ns = start_ns + (t_s * 1e9).round() as u64;
        stamps.push(frame.monotonic_ns);
        clients.retain_mut(|c| frame.write_to(c, &peer).is_ok());
        Ok(())
    })?;
    for (f, ns) in truth.iter_mut().zip(&stamps) {
        f.monotonic_ns = *ns;
    }
    if let Some(dir) = &spec.truth_dir {
        write_truth(dir, rig, spec, &truth)?;
    }
    let count = |s: &str| truth.iter().filter(|f| f.stream == s).count();
    announce(
        "walk_done",
        &format!("thermal={} rgb={}", count("thermal"), count("rgb")),
    );
    for c in &mut clients {
        let _ = c.flush();
    }
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = std::fs::remove_file(socket);
    Ok(())
}
