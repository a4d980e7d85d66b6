//! The walk's trajectories ([`world_from_thermal`]): the `orbit` circle and the `handheld`
//! walk around the scene, seeded ([`WalkPath`]; module docs of [`super`]).

use glam::{DMat3, DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_calib::Rigid3;

use super::WalkKind;

/// The point every walk looks at, metres.
pub const WALK_TARGET: DVec3 = DVec3::new(0.0, 0.0, 0.2);
/// Radius of the walk around [`WALK_TARGET`], metres.
pub const WALK_RADIUS_M: f64 = 1.7;
/// Mean angular speed around the scene, rad/s.
pub const WALK_RATE_RAD_S: f64 = 0.25;

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
