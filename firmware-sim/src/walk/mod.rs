//! `run --walk`: the rig moves through a scene, and both cameras see it move.
//!
//! **Scene** ([`trace_walk`]): the `objects` layout of [`crate::scene`] (heated pipe, box with an
//! emissivity edge, floor with an underfloor pipe, finned radiator; its thermal field
//! unchanged) inside a room: the floor extended to ±[`ROOM_HALF_M`] and four walls
//! [`ROOM_HEIGHT_M`] high at 290 K (ε 0.9, thermally bland). Every surface carries a seeded,
//! non-repeating, multi-scale albedo texture ([`texture`]: value noise at 3–40 cycles per metre
//! times the surface's colour) that feature matchers can use; the thermal images do not see it.
//! AprilTags are printed low on the walls and on the floor ([`fiducials`]; RGB only, or
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
//!
//! **Modules**: [`path`] (the trajectories), [`room`] (the room around the scene: surfaces,
//! texture, board, tracer), [`fiducials`] (the AprilTags on its walls and floor and their map),
//! [`frames`] (rendering and sensing every frame of a walk), [`truth`] (`truth.json` and the
//! maps beside it), [`socket`] (serving a walk on a Unix socket).

use std::path::PathBuf;

use crate::sensor::{RgbProfile, ThermalProfile};

pub mod fiducials;
pub mod frames;
pub mod path;
pub mod room;
pub mod socket;
pub mod truth;

pub use fiducials::TagInk;
pub use frames::{WALK_RGB_HZ, run_walk};
pub use path::{WALK_RADIUS_M, WALK_RATE_RAD_S, WALK_TARGET, WalkPath, world_from_thermal};
pub use room::{
    ROOM_WALL_K, WALK_BOARD_AZIMUTH_DEG, WALK_BOARD_K, WALK_BOARD_LEAN_DEG, WALK_BOARD_RADIUS_M,
    WalkRoom, scene_extent, texture, trace_walk, walk_board_pose, walk_tags,
};
pub use socket::serve_walk;
pub use truth::{TruthFrame, write_truth};

/// Half-size of the room around the scene (floor and walls), metres.
pub const ROOM_HALF_M: f64 = 3.0;
/// Height of the room's walls, metres.
pub const ROOM_HEIGHT_M: f64 = 2.5;

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

/// What the serving loop needs of the rig.
#[derive(Debug)]
pub struct WalkRig {
    pub thermal: ThermalProfile,
    pub rgb: Option<RgbProfile>,
    pub seed: u64,
}
