//! Pinhole camera with Brown–Conrady distortion: the model `s3tir-calib` solves, the simulated
//! rig renders with, and the trainer undistorts by. It is OpenCV's 5-parameter model
//! (k1, k2, p1, p2, k3), so values move between tools without conversion.
//!
//! Pixel coordinates have their origin at the *centre* of the top-left pixel (OpenCV's
//! convention): the pixel grid point (u, v) = (0, 0) is the middle of pixel [0][0].

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::CalibError;

/// Pinhole intrinsics in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Brown–Conrady distortion (OpenCV order k1, k2, p1, p2, k3), applied to normalised
/// coordinates (x, y) = (X/Z, Y/Z).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BrownConrady {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl BrownConrady {
    /// Distorts a normalised point.
    pub fn distort(&self, p: DVec2) -> DVec2 {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        DVec2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Jacobian of [`Self::distort`] as columns (∂/∂x, ∂/∂y).
    fn jacobian(&self, p: DVec2) -> (DVec2, DVec2) {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r2)
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let dxd_dx = radial + x * dradial * 2.0 * x + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
        let dxd_dy = x * dradial * 2.0 * y + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dyd_dx = y * dradial * 2.0 * x + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dyd_dy = radial + y * dradial * 2.0 * y + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
        (DVec2::new(dxd_dx, dyd_dx), DVec2::new(dxd_dy, dyd_dy))
    }

    /// Inverts [`Self::distort`] by Newton's method from the distorted point.
    /// Returns `None` when it does not converge (far outside the model's valid field).
    pub fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        let mut p = distorted;
        for _ in 0..50 {
            let residual = self.distort(p) - distorted;
            if residual.length_squared() < 1e-26 {
                return Some(p);
            }
            let (cx, cy) = self.jacobian(p);
            let det = cx.x * cy.y - cy.x * cx.y;
            if !det.is_finite() || det.abs() < 1e-12 {
                return None;
            }
            let step = DVec2::new(
                (cy.y * residual.x - cy.x * residual.y) / det,
                (-cx.y * residual.x + cx.x * residual.y) / det,
            );
            p -= step;
            if !p.is_finite() {
                return None;
            }
        }
        ((self.distort(p) - distorted).length() < 1e-9).then_some(p)
    }
}

/// A calibrated camera: image size, intrinsics and distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub width_px: u32,
    pub height_px: u32,
    pub intrinsics: Intrinsics,
    pub distortion: BrownConrady,
}

impl CameraModel {
    /// Checks that every parameter is finite and the focal lengths are positive.
    pub fn validate(&self) -> Result<(), CalibError> {
        let i = &self.intrinsics;
        for (parameter, value) in [("fx", i.fx), ("fy", i.fy)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(CalibError::InvalidModel {
                    parameter,
                    value,
                    why: "focal length must be finite and positive",
                });
            }
        }
        let d = &self.distortion;
        for (parameter, value) in [
            ("cx", i.cx),
            ("cy", i.cy),
            ("k1", d.k1),
            ("k2", d.k2),
            ("p1", d.p1),
            ("p2", d.p2),
            ("k3", d.k3),
        ] {
            if !value.is_finite() {
                return Err(CalibError::InvalidModel {
                    parameter,
                    value,
                    why: "must be finite",
                });
            }
        }
        Ok(())
    }

    /// Projects a point in the camera frame (x right, y down, z forward, metres) to pixels.
    /// `None` for points at or behind the camera plane.
    pub fn project(&self, point_in_cam: DVec3) -> Option<DVec2> {
        if point_in_cam.z <= 0.0 || !point_in_cam.is_finite() {
            return None;
        }
        let normalised = DVec2::new(point_in_cam.x, point_in_cam.y) / point_in_cam.z;
        Some(self.normalised_to_pixel(self.distortion.distort(normalised)))
    }

    /// The undistorted normalised ray (x, y, 1) through a pixel, or `None` when the distortion
    /// cannot be inverted there.
    pub fn unproject(&self, pixel: DVec2) -> Option<DVec3> {
        let i = &self.intrinsics;
        let distorted = DVec2::new((pixel.x - i.cx) / i.fx, (pixel.y - i.cy) / i.fy);
        self.distortion
            .undistort(distorted)
            .map(|p| DVec3::new(p.x, p.y, 1.0))
    }

    fn normalised_to_pixel(&self, p: DVec2) -> DVec2 {
        let i = &self.intrinsics;
        DVec2::new(i.fx * p.x + i.cx, i.fy * p.y + i.cy)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use proptest::prelude::*;

    fn lepton_like() -> CameraModel {
        CameraModel {
            width_px: 160,
            height_px: 120,
            intrinsics: Intrinsics {
                fx: 140.0,
                fy: 141.0,
                cx: 79.5,
                cy: 59.5,
            },
            distortion: BrownConrady {
                k1: -0.32,
                k2: 0.12,
                p1: 0.001,
                p2: -0.0015,
                k3: -0.02,
            },
        }
    }

    #[test]
    fn distortion_matches_hand_computed_value() {
        let d = BrownConrady {
            k1: 0.1,
            k2: 0.01,
            p1: 0.001,
            p2: 0.002,
            k3: 0.0,
        };
        // x = 0.5, y = -0.25: r2 = 0.3125, radial = 1 + 0.03125 + 0.0009765625 = 1.0322265625
        let p = d.distort(DVec2::new(0.5, -0.25));
        let want_x = 0.5 * 1.0322265625 + 2.0 * 0.001 * 0.5 * -0.25 + 0.002 * (0.3125 + 0.5);
        let want_y = -0.25 * 1.0322265625 + 0.001 * (0.3125 + 0.125) + 2.0 * 0.002 * 0.5 * -0.25;
        assert!(
            (p.x - want_x).abs() < 1e-15 && (p.y - want_y).abs() < 1e-15,
            "got {p}"
        );
    }

    #[test]
    fn principal_point_projects_the_optical_axis() {
        let cam = lepton_like();
        let px = cam.project(DVec3::new(0.0, 0.0, 2.0)).unwrap();
        assert!((px - DVec2::new(79.5, 59.5)).length() < 1e-12, "got {px}");
        assert!(
            cam.project(DVec3::new(0.0, 0.0, -1.0)).is_none(),
            "behind camera must not project"
        );
    }

    #[test]
    fn non_finite_parameters_are_rejected_by_name() {
        let mut cam = lepton_like();
        cam.distortion.k2 = f64::NAN;
        let msg = cam.validate().unwrap_err().to_string();
        assert!(msg.contains("k2"), "got: {msg}");
    }

    proptest! {
        #[test]
        fn unproject_inverts_project_inside_the_image(u in 0.0f64..160.0, v in 0.0f64..120.0, depth in 0.2f64..20.0) {
            let cam = lepton_like();
            let ray = cam.unproject(DVec2::new(u, v)).unwrap();
            let back = cam.project(ray * depth).unwrap();
            prop_assert!((back - DVec2::new(u, v)).length() < 1e-8, "pixel ({u}, {v}) came back as {back}");
        }
    }
}
