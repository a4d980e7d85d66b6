//! The pinhole camera of the CPU reference renderer.
//!
//! Conventions (see `docs/CONVENTIONS.md`): camera frame x right, y down, z forward (OpenCV);
//! pixel `(u, v)` with the origin at the **centre** of the top-left pixel, so pixel `(i, j)` of the
//! image is the ray through `(u, v) = (i, j)`; `cam_from_world` maps world points into the
//! camera frame. Lens distortion is removed when a dataset is loaded, so this model is pinhole
//! only.

use s3tir_calib::Rigid3;

use crate::error::RenderError;

/// Pinhole intrinsics, image size and pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub width: usize,
    pub height: usize,
    pub cam_from_world: Rigid3,
}

impl PinholeCamera {
    /// Rejects non-positive or non-finite focal lengths and empty images.
    pub fn validate(&self) -> Result<(), RenderError> {
        let ok = |x: f64| x.is_finite();
        if !(self.fx_px > 0.0 && self.fy_px > 0.0 && ok(self.fx_px) && ok(self.fy_px)) {
            return Err(RenderError::InvalidCamera {
                camera: "pinhole",
                reason: "focal lengths must be finite and positive",
            });
        }
        if !(ok(self.cx_px) && ok(self.cy_px)) {
            return Err(RenderError::InvalidCamera {
                camera: "pinhole",
                reason: "principal point must be finite",
            });
        }
        if self.width == 0 || self.height == 0 {
            return Err(RenderError::InvalidCamera {
                camera: "pinhole",
                reason: "empty image",
            });
        }
        Ok(())
    }

    /// Camera centre in world coordinates (metres).
    pub fn centre_world(&self) -> [f64; 3] {
        self.cam_from_world.inverse().translation_m.to_array()
    }

    /// Row-major `R_cam_from_world`.
    pub fn rotation_cam_from_world(&self) -> [f64; 9] {
        let m = self.cam_from_world.rotation_matrix();
        [
            m.x_axis.x, m.y_axis.x, m.z_axis.x, m.x_axis.y, m.y_axis.y, m.z_axis.y, m.x_axis.z,
            m.y_axis.z, m.z_axis.z,
        ]
    }

    /// Row-major `W = R_world_from_cam · K⁻¹`: the world ray direction of pixel `(u, v)` is
    /// `W · (u, v, 1)`, scaled so that its camera-z component is 1 (the ray parameter `t` is the
    /// camera-frame depth z).
    pub fn pixel_to_world_dir(&self) -> [f64; 9] {
        let r = self.rotation_cam_from_world();
        // K⁻¹ = [[1/fx, 0, −cx/fx], [0, 1/fy, −cy/fy], [0, 0, 1]]
        let kinv = [
            1.0 / self.fx_px,
            0.0,
            -self.cx_px / self.fx_px,
            0.0,
            1.0 / self.fy_px,
            -self.cy_px / self.fy_px,
            0.0,
            0.0,
            1.0,
        ];
        let rt = [r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]];
        crate::real::v3::mat_mul(&rt, &kinv)
    }

    /// The same camera read out at `k`× the resolution (same pose and field of view):
    /// focal lengths × k, principal point scaled about the pixel-centre origin
    /// (`c' = (c + ½)·k − ½`), image size × k. Renders super-resolved views.
    pub fn scaled(&self, k: usize) -> Self {
        let s = k as f64;
        Self {
            fx_px: self.fx_px * s,
            fy_px: self.fy_px * s,
            cx_px: (self.cx_px + 0.5) * s - 0.5,
            cy_px: (self.cy_px + 0.5) * s - 0.5,
            width: self.width * k,
            height: self.height * k,
            cam_from_world: self.cam_from_world,
        }
    }

    /// Camera-frame point of a world point.
    pub fn to_cam(&self, p_world: [f64; 3]) -> [f64; 3] {
        self.cam_from_world
            .transform_point(glam::DVec3::from_array(p_world))
            .to_array()
    }

    /// Pixel of a camera-frame point (any z; the caller checks z > near).
    pub fn project_cam(&self, p_cam: [f64; 3]) -> [f64; 2] {
        [
            self.fx_px * p_cam[0] / p_cam[2] + self.cx_px,
            self.fy_px * p_cam[1] / p_cam[2] + self.cy_px,
        ]
    }

    /// World point at camera depth `z` along the ray of pixel `(u, v)`.
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> [f64; 3] {
        let p_cam = glam::DVec3::new(
            (u - self.cx_px) / self.fx_px * z,
            (v - self.cy_px) / self.fy_px * z,
            z,
        );
        self.cam_from_world
            .inverse()
            .transform_point(p_cam)
            .to_array()
    }

    /// A camera at `eye` looking at `target` with world `up` (for tests and demos).
    pub fn look_at(
        eye: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        f_px: f64,
        width: usize,
        height: usize,
    ) -> Self {
        use glam::DVec3;
        let eye = DVec3::from_array(eye);
        let fwd = (DVec3::from_array(target) - eye).normalize_or(DVec3::Z);
        let mut right = fwd.cross(DVec3::from_array(up));
        if right.length_squared() < 1e-24 {
            right = fwd.any_orthonormal_vector();
        }
        let right = right.normalize();
        // camera y points down: y = z × x
        let down = fwd.cross(right);
        // world_from_cam columns are the camera axes in world coordinates
        let world_from_cam_rot = glam::DMat3::from_cols(right, down, fwd);
        let rot = glam::DQuat::from_mat3(&world_from_cam_rot);
        let world_from_cam = Rigid3::new(rot, eye);
        Self {
            fx_px: f_px,
            fy_px: f_px,
            cx_px: (width as f64 - 1.0) / 2.0,
            cy_px: (height as f64 - 1.0) / 2.0,
            width,
            height,
            cam_from_world: world_from_cam.inverse(),
        }
    }
}
