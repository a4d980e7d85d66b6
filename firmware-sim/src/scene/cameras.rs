//! Camera paths of the scene datasets: the pinhole [`scene_camera`] and its poses, the
//! `Objects` layout's [`orbit`] and the `Wall` layout's [`wall_arc`] ([`poses`]).

use glam::{DMat3, DQuat, DVec3};
use s3tir_calib::{BrownConrady, CameraModel, Intrinsics, Rigid3};

use super::SceneLayout;
use super::objects::{WALL_EDGE_X, WALL_Y};

/// `cam_from_world` of a camera at `eye` looking at `target` (world z up, image y down).
pub fn look_at(eye: DVec3, target: DVec3) -> Rigid3 {
    let fwd = (target - eye).normalize();
    let right = fwd.cross(DVec3::Z).normalize();
    let down = fwd.cross(right);
    let world_from_cam = Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(right, down, fwd)), eye);
    world_from_cam.inverse()
}

/// The orbit: `n` cameras evenly spaced in azimuth.
pub fn orbit(n: usize) -> Vec<Rigid3> {
    let target = DVec3::new(0.0, 0.0, 0.15);
    (0..n)
        .map(|k| {
            // View 0 sits near the +y axis (0.1 rad past it), so it and view n/2 (the trainer's
            // default hold-out of every 8th view, for n = 16) see the pipe from the side, the
            // box's emissivity edge face-on.
            let a = 2.0 * std::f64::consts::PI * k as f64 / n.max(1) as f64
                + std::f64::consts::FRAC_PI_2
                + 0.1;
            let eye = DVec3::new(1.6 * a.cos(), 1.6 * a.sin(), 0.9);
            look_at(eye, target)
        })
        .collect()
}

/// The wall layout's cameras: `n` poses on an arc in front of the wall (module docs).
pub fn wall_arc(n: usize) -> Vec<Rigid3> {
    let target = DVec3::new(WALL_EDGE_X, WALL_Y, 0.95);
    (0..n)
        .map(|k| {
            let f = if n > 1 {
                k as f64 / (n - 1) as f64
            } else {
                0.5
            };
            let yaw = (-25.0 + 50.0 * f).to_radians();
            let dz = 0.15 * ((k % 3) as f64 - 1.0);
            let eye = target + DVec3::new(1.6 * yaw.sin(), -1.6 * yaw.cos(), dz);
            look_at(eye, target)
        })
        .collect()
}

/// The `n` camera poses (`cam_from_world`) of `layout`: [`orbit`] or [`wall_arc`].
pub fn poses(layout: SceneLayout, n: usize) -> Vec<Rigid3> {
    match layout {
        SceneLayout::Objects => orbit(n),
        SceneLayout::Wall | SceneLayout::Facade => wall_arc(n),
    }
}

/// The pinhole camera of a `width × height` scene image (57° horizontal field of view).
pub fn scene_camera(width_px: u32, height_px: u32) -> CameraModel {
    let f = f64::from(width_px) / 2.0 / (28.5f64.to_radians()).tan();
    CameraModel {
        width_px,
        height_px,
        intrinsics: Intrinsics {
            fx: f,
            fy: f,
            cx: (f64::from(width_px) - 1.0) / 2.0,
            cy: (f64::from(height_px) - 1.0) / 2.0,
        },
        distortion: BrownConrady::default(),
    }
}
