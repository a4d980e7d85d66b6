//! Camera poses between registered keyframes, on the capture clock (`monotonic_ns`, shared by
//! both cameras of a rig): rotation by slerp, camera centre linearly, between the two
//! registered keyframes around the time, when they are at most `max_gap_s` apart.

use crate::geometry::Rigid3;

/// Registered keyframes in time order: `(monotonic_ns, world_from_cam)`.
#[derive(Debug, Clone)]
pub struct Track {
    keys: Vec<(u64, Rigid3)>,
    max_gap_ns: u64,
}

impl Track {
    pub fn new(registered: &[(u64, Rigid3)], max_gap_s: f64) -> Self {
        let mut keys = registered.to_vec();
        keys.sort_by_key(|k| k.0);
        keys.dedup_by_key(|k| k.0);
        Self {
            keys,
            max_gap_ns: (max_gap_s.max(0.0) * 1e9) as u64,
        }
    }

    /// Number of registered keyframes.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The camera's pose at `t_ns`, or `None` outside the track or across a gap.
    pub fn world_from_cam(&self, t_ns: u64) -> Option<Rigid3> {
        let i = self.keys.partition_point(|k| k.0 <= t_ns);
        // keys[i-1].0 <= t < keys[i].0
        if i == 0 {
            return None;
        }
        let (t0, a) = self.keys[i - 1];
        if t0 == t_ns {
            return Some(a);
        }
        let (t1, b) = *self.keys.get(i)?;
        if t1 - t0 > self.max_gap_ns {
            return None;
        }
        let s = (t_ns - t0) as f64 / (t1 - t0) as f64;
        // world_from_cam: the translation is the camera centre in the world.
        let rotation = a.rotation.slerp(b.rotation, s);
        let centre = a.translation_m.lerp(b.translation_m, s);
        Some(Rigid3::new(rotation, centre))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use glam::{DQuat, DVec3};

    #[test]
    fn interpolates_between_keys_and_refuses_gaps_and_ends() {
        let a = Rigid3::new(DQuat::IDENTITY, DVec3::ZERO);
        let b = Rigid3::new(DQuat::from_rotation_y(0.2), DVec3::new(1.0, 0.0, 0.0));
        let c = Rigid3::new(DQuat::from_rotation_y(0.4), DVec3::new(2.0, 0.0, 0.0));
        let track = Track::new(&[(1_000_000_000, b), (0, a), (5_000_000_000, c)], 1.5);
        let mid = track.world_from_cam(500_000_000).expect("inside the track");
        assert!((mid.translation_m - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-12);
        assert!((mid.rotation.angle_between(DQuat::from_rotation_y(0.1))).abs() < 1e-12);
        assert_eq!(track.world_from_cam(1_000_000_000), Some(b), "on a key");
        assert_eq!(track.world_from_cam(3_000_000_000), None, "4 s gap > 1.5 s");
        assert_eq!(
            track.world_from_cam(6_000_000_000),
            None,
            "after the last key"
        );
    }
}
