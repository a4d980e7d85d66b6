//! Camera poses between registered keyframes, on the capture clock (`monotonic_ns`, shared by
//! both cameras of a rig): rotation by slerp, camera centre linearly, between the two
//! registered keyframes around the time, when they are at most `max_gap_s` apart.

use crate::model::geometry::Rigid3;

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

    /// The registered keyframes, `(monotonic_ns, world_from_cam)` in time order (one per
    /// capture time): the poses every interpolated one is made of, in the same world.
    pub fn keys(&self) -> &[(u64, Rigid3)] {
        &self.keys
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

/// How far one keyframe's pose is from the interpolation of two neighbours in time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jump {
    pub t_ns: u64,
    /// Rotation between the pose and the neighbours' slerp, degrees.
    pub turn_deg: f64,
    /// Camera centre's distance from the neighbours' linear interpolation (world units).
    pub moved: f64,
    /// Distance between the two neighbours' centres (world units).
    pub span: f64,
}

/// How far `keys[i]` is from the interpolation of `keys[a]` and `keys[b]` (`a < i < b`).
pub fn jump(keys: &[(u64, Rigid3)], a: usize, i: usize, b: usize) -> Option<Jump> {
    let ((t0, p0), (t, pose), (t1, p1)) = (*keys.get(a)?, *keys.get(i)?, *keys.get(b)?);
    let expected = Track::new(&[(t0, p0), (t1, p1)], f64::INFINITY).world_from_cam(t)?;
    Some(Jump {
        t_ns: t,
        turn_deg: expected.rotation.angle_between(pose.rotation).to_degrees(),
        moved: (expected.translation_m - pose.translation_m).length(),
        span: (p1.translation_m - p0.translation_m).length(),
    })
}

/// Drops outlier poses from `keys` (time order), worst first. A key is judged against each
/// pair of neighbours among the [`JUDGES`] nearest before and after it (each within
/// `neighbour_s`), and keeps the kindest verdict: two bad keys side by side (an RGB keyframe
/// pair registered together) make their good neighbours look off through one another, never
/// through all the pairs. While the worst key's `badness(jump)` exceeds 1, it is removed and
/// the others judged again without it. Keys without a neighbour on a side are not judged.
/// Returns the capture times dropped.
pub fn drop_worst_jumps(
    keys: &mut Vec<(u64, Rigid3)>,
    neighbour_s: f64,
    badness: impl Fn(&Jump) -> f64,
) -> Vec<u64> {
    let gap_ns = (neighbour_s.max(0.0) * 1e9) as u64;
    let mut dropped = Vec::new();
    loop {
        let n = keys.len();
        let mut worst: Option<(f64, usize)> = None;
        for i in 1..n.saturating_sub(1) {
            let t = keys[i].0;
            let before = (i.saturating_sub(JUDGES)..i).filter(|&a| t - keys[a].0 <= gap_ns);
            let kindest = before
                .flat_map(|a| {
                    (i + 1..(i + 1 + JUDGES).min(n))
                        .filter(|&b| keys[b].0 - t <= gap_ns)
                        .map(move |b| (a, b))
                })
                .filter_map(|(a, b)| jump(keys, a, i, b))
                .map(|j| badness(&j))
                .min_by(f64::total_cmp);
            if let Some(b) = kindest
                && b > 1.0
                && worst.is_none_or(|w| b >= w.0)
            {
                worst = Some((b, i));
            }
        }
        let Some((_, i)) = worst else {
            return dropped;
        };
        dropped.push(keys.remove(i).0);
    }
}

/// [`drop_worst_jumps`]: neighbours on each side a key is judged against.
pub const JUDGES: usize = 3;

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

    #[test]
    fn a_jump_is_measured_against_the_interpolation_of_two_neighbours() {
        let key = |t_s: f64, deg: f64, x: f64| {
            (
                (t_s * 1e9) as u64,
                Rigid3::new(
                    DQuat::from_rotation_z(deg.to_radians()),
                    DVec3::new(x, 0.0, 0.0),
                ),
            )
        };
        let keys = [key(0.1, 1.0, 1.0), key(0.2, 7.0, 5.0), key(0.4, 4.0, 4.0)];
        let j = jump(&keys, 0, 1, 2).expect("three keys");
        assert!(
            (j.turn_deg - 5.0).abs() < 1e-9 && (j.moved - 3.0).abs() < 1e-9,
            "the key at 0.2 s is 5° and 3 units off the interpolation at 1/3: {j:?}"
        );
        assert!(
            (j.span - 3.0).abs() < 1e-9,
            "neighbours 3 units apart: {j:?}"
        );
        assert_eq!(jump(&keys, 0, 1, 3), None, "no fourth key");
    }

    #[test]
    fn the_worst_jump_goes_first_and_its_good_neighbours_stay() {
        let key = |i: u64, deg: f64| {
            (
                i * 100_000_000,
                Rigid3::new(
                    DQuat::from_rotation_z(deg.to_radians()),
                    DVec3::new(i as f64, 0.0, 0.0),
                ),
            )
        };
        // A steady 1° per 0.1 s; keys 4 and 5 both registered 15° off; a last key too far
        // from the others to be judged or to judge.
        let mut keys: Vec<_> = (0..10)
            .map(|i| key(i, i as f64 + if i == 4 || i == 5 { 15.0 } else { 0.0 }))
            .collect();
        keys.push(key(30, 50.0));
        let through_4 = jump(&keys, 2, 3, 4).expect("keys");
        assert!(
            through_4.turn_deg > 7.0,
            "judged through the bad key 4 alone, the good key 3 looks off: {through_4:?}"
        );
        let mut dropped = drop_worst_jumps(&mut keys, 0.7, |j| j.turn_deg / 2.0);
        dropped.sort_unstable();
        assert_eq!(
            dropped,
            vec![400_000_000, 500_000_000],
            "only the two bad keys go"
        );
        assert_eq!(keys.len(), 9, "the far key is neither judged nor dropped");
    }
}
