//! Rigid transforms named by the frames they connect: `b_from_a` maps a point expressed in
//! frame `a` into frame `b` (`p_b = b_from_a * p_a`). See `docs/CONVENTIONS.md`.

use glam::{DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

/// A rigid transform `p_to = rotation * p_from + translation_m`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rigid3 {
    /// Unit quaternion.
    pub rotation: DQuat,
    /// Translation in metres.
    pub translation_m: DVec3,
}

impl Rigid3 {
    pub const IDENTITY: Rigid3 = Rigid3 {
        rotation: DQuat::IDENTITY,
        translation_m: DVec3::ZERO,
    };

    pub fn new(rotation: DQuat, translation_m: DVec3) -> Self {
        Self {
            rotation: rotation.normalize(),
            translation_m,
        }
    }

    /// Maps a point from the source frame into the target frame.
    pub fn transform_point(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation_m
    }

    /// Rotates a direction (no translation).
    pub fn transform_vector(&self, v: DVec3) -> DVec3 {
        self.rotation * v
    }

    /// `a_from_b` given `b_from_a`.
    pub fn inverse(&self) -> Self {
        let inv = self.rotation.conjugate();
        Self {
            rotation: inv,
            translation_m: -(inv * self.translation_m),
        }
    }

    /// `c_from_a = c_from_b.compose(&b_from_a)`.
    pub fn compose(&self, b_from_a: &Rigid3) -> Self {
        Self {
            rotation: (self.rotation * b_from_a.rotation).normalize(),
            translation_m: self.rotation * b_from_a.translation_m + self.translation_m,
        }
    }

    /// Rotation as a matrix (row-major access via `DMat3::row`).
    pub fn rotation_matrix(&self) -> DMat3 {
        DMat3::from_quat(self.rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_with_inverse_is_identity() {
        let b_from_a = Rigid3::new(
            DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.2, 1.1),
            DVec3::new(0.1, -0.05, 0.02),
        );
        let p = DVec3::new(0.4, 2.0, -1.0);
        let back = b_from_a.inverse().compose(&b_from_a).transform_point(p);
        assert!(
            (back - p).length() < 1e-12,
            "a_from_b * b_from_a moved {p} to {back}"
        );
        let c_from_b = Rigid3::new(DQuat::from_rotation_z(0.5), DVec3::X);
        let c_from_a = c_from_b.compose(&b_from_a);
        let want = c_from_b.transform_point(b_from_a.transform_point(p));
        assert!((c_from_a.transform_point(p) - want).length() < 1e-12);
    }
}
