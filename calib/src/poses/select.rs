//! Which frames the poses stage uses, and why (module docs of [`super`]): keyframes for
//! structure from motion, thermal candidates, then thinned and held-out thermal views.

use std::collections::BTreeMap;

use glam::DVec3;
use serde::Serialize;

use super::PosesOptions;
use super::frames::FrameInfo;
use super::interp::Track;
use super::stats::median;
use crate::model::geometry::Rigid3;

/// What happened to one frame (`poses.json`).
#[derive(Debug, Clone, Serialize)]
pub struct FrameDecision {
    pub stream: &'static str,
    pub sequence: u32,
    pub monotonic_ns: u64,
    /// `keyframe`, `view`, `held_out`, or why it was skipped.
    pub decision: String,
}

/// A posed thermal view chosen for the dataset.
#[derive(Debug, Clone, Copy)]
pub struct ThermalView {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub world_from_cam: Rigid3,
    pub held_out: bool,
}

/// A posed RGB keyframe written into the dataset (`--with-rgb`, [`rgb_views`]).
#[derive(Debug, Clone, Copy)]
pub struct RgbView {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub world_from_cam: Rigid3,
    pub held_out: bool,
}

/// Scene depth: the median distance from the cameras' `centres` to the SfM points' median
/// (1 without points: the fast path's tags are passed as points, so only an empty model has
/// none).
pub(super) fn scene_depth(centres: &[DVec3], points: &[[f64; 3]]) -> f64 {
    if points.is_empty() {
        return 1.0;
    }
    let c = DVec3::new(
        median(&points.iter().map(|p| p[0]).collect::<Vec<_>>()),
        median(&points.iter().map(|p| p[1]).collect::<Vec<_>>()),
        median(&points.iter().map(|p| p[2]).collect::<Vec<_>>()),
    );
    median(
        &centres
            .iter()
            .map(|x| (*x - c).length())
            .collect::<Vec<_>>(),
    )
    .max(1e-9)
}

/// Whether each frame is motion-blurred: sharpness below `ratio` × the median of its
/// ±`window` neighbours (the frame itself excluded).
pub fn blurred(frames: &[FrameInfo], ratio: f64, window: usize) -> Vec<bool> {
    (0..frames.len())
        .map(|i| {
            let lo = i.saturating_sub(window);
            let hi = (i + window + 1).min(frames.len());
            let local: Vec<f64> = (lo..hi)
                .filter(|&j| j != i && !frames[j].ffc_frozen)
                .map(|j| frames[j].sharpness)
                .collect();
            !local.is_empty() && frames[i].sharpness < ratio * median(&local)
        })
        .collect()
}

/// Picks the sharpest usable frame of each time slot of `1 / keyframe_hz` seconds (slots widen
/// so that at most `max_keyframes` are chosen). Frozen (FFC) and blurred frames are never
/// keyframes.
pub fn keyframes(frames: &[FrameInfo], opts: &PosesOptions) -> Vec<FrameInfo> {
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
        return Vec::new();
    };
    let blur = blurred(frames, opts.blur_ratio, opts.blur_window);
    let span_s = (last.monotonic_ns - first.monotonic_ns) as f64 * 1e-9;
    let mut slot_s = 1.0 / opts.keyframe_hz.max(1e-3);
    if opts.max_keyframes > 0 && span_s / slot_s > opts.max_keyframes as f64 {
        slot_s = span_s / opts.max_keyframes as f64;
    }
    let mut best: BTreeMap<u64, FrameInfo> = BTreeMap::new();
    for (f, &b) in frames.iter().zip(&blur) {
        if b || f.ffc_frozen {
            continue;
        }
        let slot = ((f.monotonic_ns - first.monotonic_ns) as f64 * 1e-9 / slot_s) as u64;
        let e = best.entry(slot).or_insert(*f);
        if f.sharpness > e.sharpness {
            *e = *f;
        }
    }
    let mut out: Vec<FrameInfo> = best.into_values().collect();
    out.truncate(opts.max_keyframes.max(1));
    out
}

/// Keyframes of the RGB stream for the thermal `targets`: for each target, the usable RGB
/// frames just before and just after it (each within `max_sync_s`), so that every thermal pose
/// is interpolated between two SfM poses one RGB period apart, never across a hand's jitter.
///
/// Then the gaps are bridged: every `1 / keyframe_hz` slot of the RGB stream that holds no
/// keyframe gets its sharpest usable frame. Where the thermal stream has no candidates (an
/// FFC, dropped frames) the RGB frames are still good, and structure from motion needs its
/// chain of overlapping keyframes unbroken: on the simulated walk the FFC left a 2.9 s (41°)
/// hole between two keyframes, and COLMAP joined the two halves across it with a hinge of a
/// few degrees in about one run of three (median rotation error 1.4–2.4° instead of 0.09°).
///
/// Duplicates merge; more than `max_keyframes` are thinned evenly.
pub fn keyframes_near(
    frames: &[FrameInfo],
    targets: &[FrameInfo],
    max_sync_s: f64,
    opts: &PosesOptions,
) -> Vec<FrameInfo> {
    let blur = blurred(frames, opts.blur_ratio, opts.blur_window);
    let max_ns = (max_sync_s * 1e9) as u64;
    let usable = |j: usize| !blur[j] && !frames[j].ffc_frozen;
    let mut chosen: BTreeMap<u64, FrameInfo> = BTreeMap::new();
    for t in targets {
        let i = frames.partition_point(|f| f.monotonic_ns <= t.monotonic_ns);
        let before = (0..i)
            .rev()
            .take(3)
            .find(|&j| usable(j))
            .filter(|&j| t.monotonic_ns - frames[j].monotonic_ns <= max_ns);
        let after = (i..frames.len())
            .take(3)
            .find(|&j| usable(j))
            .filter(|&j| frames[j].monotonic_ns - t.monotonic_ns <= max_ns);
        for j in before.into_iter().chain(after) {
            chosen.insert(frames[j].monotonic_ns, frames[j]);
        }
    }
    if let Some(first) = frames.first() {
        let slot_ns = ((1e9 / opts.keyframe_hz.max(1e-3)) as u64).max(1);
        let slot = |f: &FrameInfo| (f.monotonic_ns - first.monotonic_ns) / slot_ns;
        let covered: std::collections::BTreeSet<u64> = chosen.values().map(slot).collect();
        let mut bridge: BTreeMap<u64, FrameInfo> = BTreeMap::new();
        for (j, f) in frames.iter().enumerate() {
            if !usable(j) || covered.contains(&slot(f)) {
                continue;
            }
            let e = bridge.entry(slot(f)).or_insert(*f);
            if f.sharpness > e.sharpness {
                *e = *f;
            }
        }
        for f in bridge.into_values() {
            chosen.insert(f.monotonic_ns, f);
        }
    }
    let all: Vec<FrameInfo> = chosen.into_values().collect();
    if opts.max_keyframes == 0 || all.len() <= opts.max_keyframes {
        return all;
    }
    let n = all.len();
    (0..opts.max_keyframes)
        .map(|i| all[i * n / opts.max_keyframes])
        .collect()
}

/// Thermal frames that may become views: not FFC-frozen, not blurred, at most `thermal_hz`
/// per second (the sharpest of each slot). Returns them with the reason every other frame was
/// left out.
pub fn thermal_candidates(
    frames: &[FrameInfo],
    opts: &PosesOptions,
) -> (Vec<FrameInfo>, Vec<FrameDecision>) {
    let blur = blurred(frames, opts.blur_ratio, opts.blur_window);
    let Some(first) = frames.first() else {
        return (Vec::new(), Vec::new());
    };
    let slot_s = 1.0 / opts.thermal_hz.max(1e-3);
    let mut best: BTreeMap<u64, FrameInfo> = BTreeMap::new();
    let mut skipped = Vec::new();
    let skip = |f: &FrameInfo, why: &str| FrameDecision {
        stream: "thermal",
        sequence: f.sequence,
        monotonic_ns: f.monotonic_ns,
        decision: why.to_owned(),
    };
    for (f, &b) in frames.iter().zip(&blur) {
        if f.ffc_frozen {
            skipped.push(skip(f, "skipped: FFC-frozen"));
            continue;
        }
        if b {
            skipped.push(skip(f, "skipped: motion-blurred"));
            continue;
        }
        let slot = ((f.monotonic_ns - first.monotonic_ns) as f64 * 1e-9 / slot_s) as u64;
        match best.get(&slot) {
            Some(e) if e.sharpness >= f.sharpness => {
                skipped.push(skip(f, "skipped: a sharper frame of the same time slot"));
            }
            Some(e) => {
                skipped.push(skip(e, "skipped: a sharper frame of the same time slot"));
                best.insert(slot, *f);
            }
            None => {
                best.insert(slot, *f);
            }
        }
    }
    (best.into_values().collect(), skipped)
}

/// Keeps at most `max` candidates (evenly spaced in time); the others are left out with the
/// reason (each RGB keyframe pair costs structure-from-motion time).
pub fn fit_keyframe_budget(candidates: &mut (Vec<FrameInfo>, Vec<FrameDecision>), max: usize) {
    let n = candidates.0.len();
    if max == 0 || n <= max {
        return;
    }
    let keep: Vec<usize> = (0..max).map(|i| i * n / max).collect();
    let all = std::mem::take(&mut candidates.0);
    for (i, f) in all.into_iter().enumerate() {
        if keep.binary_search(&i).is_ok() {
            candidates.0.push(f);
        } else {
            candidates.1.push(FrameDecision {
                stream: "thermal",
                sequence: f.sequence,
                monotonic_ns: f.monotonic_ns,
                decision: "skipped: over the keyframe budget (--max-keyframes)".into(),
            });
        }
    }
}

/// Poses the candidates, thins near-duplicates, caps the count and marks the held-out views.
/// Returns the views, every candidate's decision (with `skipped` prepended), and counts per
/// reason.
pub fn thermal_views(
    candidates: &(Vec<FrameInfo>, Vec<FrameDecision>),
    track: &Track,
    sfm_from_thermal: &Rigid3,
    points: &[[f64; 3]],
    opts: &PosesOptions,
) -> (
    Vec<ThermalView>,
    Vec<FrameDecision>,
    BTreeMap<String, usize>,
) {
    let (cands, skipped) = candidates;
    let mut decisions: Vec<FrameDecision> = skipped.clone();
    let mut posed: Vec<ThermalView> = Vec::new();
    for f in cands {
        match track.world_from_cam(f.monotonic_ns) {
            Some(world_from_sfm) => posed.push(ThermalView {
                sequence: f.sequence,
                monotonic_ns: f.monotonic_ns,
                world_from_cam: world_from_sfm.compose(sfm_from_thermal),
                held_out: false,
            }),
            None => decisions.push(FrameDecision {
                stream: "thermal",
                sequence: f.sequence,
                monotonic_ns: f.monotonic_ns,
                decision: "skipped: no posed keyframe close enough on both sides (max_gap_s; with RGB, its own bracket)".into(),
            }),
        }
    }
    let centres: Vec<DVec3> = posed
        .iter()
        .map(|v| v.world_from_cam.translation_m)
        .collect();
    let depth = scene_depth(&centres, points);
    let mut kept: Vec<ThermalView> = Vec::new();
    for v in posed {
        let moved = kept.last().is_none_or(|k| {
            let baseline =
                (v.world_from_cam.translation_m - k.world_from_cam.translation_m).length() / depth;
            let turn_deg = v
                .world_from_cam
                .rotation
                .angle_between(k.world_from_cam.rotation)
                .to_degrees();
            baseline >= opts.min_baseline || turn_deg >= opts.min_rotation_deg
        });
        if moved {
            kept.push(v);
        } else {
            decisions.push(FrameDecision {
                stream: "thermal",
                sequence: v.sequence,
                monotonic_ns: v.monotonic_ns,
                decision: "skipped: near-duplicate of the previous view (baseline and rotation below the thinning thresholds)".into(),
            });
        }
    }
    if opts.max_views > 0 && kept.len() > opts.max_views {
        // Evenly spaced subset.
        let n = kept.len();
        let keep: Vec<usize> = (0..opts.max_views)
            .map(|i| i * n / opts.max_views)
            .collect();
        let mut subset = Vec::with_capacity(keep.len());
        for (i, v) in kept.into_iter().enumerate() {
            if keep.binary_search(&i).is_ok() {
                subset.push(v);
            } else {
                decisions.push(FrameDecision {
                    stream: "thermal",
                    sequence: v.sequence,
                    monotonic_ns: v.monotonic_ns,
                    decision: format!("skipped: over --max-views {}", opts.max_views),
                });
            }
        }
        kept = subset;
    }
    let k = opts.holdout_every;
    for (i, v) in kept.iter_mut().enumerate() {
        // Hold out views k/2, k/2 + k, …: never the first or last (their poses sit at the
        // ends of the track).
        v.held_out = k > 1 && i % k == k / 2;
        decisions.push(FrameDecision {
            stream: "thermal",
            sequence: v.sequence,
            monotonic_ns: v.monotonic_ns,
            decision: if v.held_out { "held_out" } else { "view" }.into(),
        });
    }
    decisions.sort_by_key(|d| (d.monotonic_ns, d.sequence));
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for d in &decisions {
        if let Some(why) = d.decision.strip_prefix("skipped: ") {
            *counts
                .entry(why.split(" (").next().unwrap_or(why).to_owned())
                .or_default() += 1;
        }
    }
    (kept, decisions, counts)
}

/// The RGB views of `--with-rgb` (module docs of [`super::dataset`]): every key of `track`, the
/// posed RGB keyframes the thermal poses are interpolated between, with its pose as it is (the
/// same world as the thermal views, by construction), named by the frame of `rgb_frames` (the
/// session's RGB frames) at its capture time. Held out: the views within `window_s` of a
/// held-out thermal view's capture time, and the one nearest to it in any case, so that a
/// held-out instant is held out in both modalities. Keys of no RGB frame (a thermal-stream
/// track) give no view.
pub fn rgb_views(
    track: &Track,
    rgb_frames: &[FrameInfo],
    thermal: &[ThermalView],
    window_s: f64,
) -> Vec<RgbView> {
    let by_time: BTreeMap<u64, u32> = rgb_frames
        .iter()
        .rev()
        .map(|f| (f.monotonic_ns, f.sequence))
        .collect();
    let mut views: Vec<RgbView> = track
        .keys()
        .iter()
        .filter_map(|&(t, world_from_cam)| {
            Some(RgbView {
                sequence: *by_time.get(&t)?,
                monotonic_ns: t,
                world_from_cam,
                held_out: false,
            })
        })
        .collect();
    if views.is_empty() {
        return views;
    }
    let window_ns = (window_s.max(0.0) * 1e9) as u64;
    for t in thermal
        .iter()
        .filter(|v| v.held_out)
        .map(|v| v.monotonic_ns)
    {
        let dt = |r: &RgbView| r.monotonic_ns.abs_diff(t);
        let nearest = (0..views.len()).min_by_key(|&i| dt(&views[i])).unwrap_or(0);
        views[nearest].held_out = true;
        for r in views.iter_mut().filter(|r| dt(r) <= window_ns) {
            r.held_out = true;
        }
    }
    views
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn frames(sharp: &[f64], ffc: &[usize]) -> Vec<FrameInfo> {
        sharp
            .iter()
            .enumerate()
            .map(|(i, &s)| FrameInfo {
                sequence: i as u32,
                monotonic_ns: i as u64 * 100_000_000, // 10 Hz
                ffc_frozen: ffc.contains(&i),
                sharpness: s,
            })
            .collect()
    }

    #[test]
    fn keyframes_skip_blurred_and_frozen_frames_and_fill_slots() {
        let mut s = vec![1.0; 40];
        s[5] = 0.2; // blurred
        s[12] = 1.5; // sharpest of its slot
        let f = frames(&s, &[20, 21, 22]);
        let opts = PosesOptions {
            keyframe_hz: 2.0,
            ..PosesOptions::default()
        };
        let k = keyframes(&f, &opts);
        assert_eq!(k.len(), 8, "4 s at 2 Hz: 8 slots, got {k:?}");
        assert!(k.iter().all(|f| f.sequence != 5), "blurred frame 5 chosen");
        assert!(
            k.iter().any(|f| f.sequence == 12),
            "sharpest frame 12 not chosen"
        );
        assert!(
            k.iter().all(|f| !(20..=22).contains(&f.sequence)),
            "frozen frame chosen"
        );
        let capped = keyframes(
            &f,
            &PosesOptions {
                keyframe_hz: 10.0,
                max_keyframes: 10,
                ..PosesOptions::default()
            },
        );
        assert!(capped.len() <= 10, "cap: {}", capped.len());
    }

    #[test]
    fn rgb_keyframes_bracket_the_thermal_targets() {
        // RGB at 10 Hz; thermal targets at 8.7 Hz-ish instants.
        let rgb = frames(&[1.0; 30], &[]);
        let targets: Vec<FrameInfo> = [0.03, 0.52, 1.249, 2.9, 9.0]
            .iter()
            .enumerate()
            .map(|(i, &t)| FrameInfo {
                sequence: i as u32,
                monotonic_ns: (t * 1e9) as u64,
                ffc_frozen: false,
                sharpness: 1.0,
            })
            .collect();
        // One bridging slot of 5 s covers the whole stream: only the brackets are chosen.
        let one_slot = PosesOptions {
            keyframe_hz: 0.2,
            ..PosesOptions::default()
        };
        let k = keyframes_near(&rgb, &targets, 0.12, &one_slot);
        let seqs: Vec<u32> = k.iter().map(|f| f.sequence).collect();
        // 0.03 → frames 0, 1; 0.52 → 5, 6; 1.249 → 12, 13; 2.9 → 29 (no frame after);
        // 9.0 → none.
        assert_eq!(
            seqs,
            vec![0, 1, 5, 6, 12, 13, 29],
            "the RGB frames around each target, within 120 ms"
        );
    }

    #[test]
    fn rgb_keyframes_bridge_a_gap_in_the_thermal_targets() {
        // RGB at 10 Hz for 4 s; thermal targets only near 0.05 s and 3.75 s (an FFC between).
        let mut sharp = vec![1.0; 40];
        sharp[13] = 1.3; // the sharpest of the slot [1.0, 1.5) s
        sharp[27] = 0.2; // blurred: never a keyframe
        sharp[26] = 1.2; // the sharpest usable of [2.5, 3.0) s
        let rgb = frames(&sharp, &[]);
        let target = |t: f64| FrameInfo {
            sequence: 0,
            monotonic_ns: (t * 1e9) as u64,
            ffc_frozen: false,
            sharpness: 1.0,
        };
        let k = keyframes_near(
            &rgb,
            &[target(0.05), target(3.75)],
            0.12,
            &PosesOptions::default(), // keyframe_hz 2: slots of 0.5 s
        );
        let seqs: Vec<u32> = k.iter().map(|f| f.sequence).collect();
        // Brackets: 0, 1 and 37, 38. Slots [0.5, 1.0) … [3.0, 3.5) get one each: the first
        // usable frame of equal sharpness, else the sharpest (13, 26).
        assert_eq!(
            seqs,
            vec![0, 1, 5, 13, 15, 20, 26, 30, 37, 38],
            "one keyframe in every 0.5 s slot between the brackets, the sharpest usable"
        );
        let capped = keyframes_near(
            &rgb,
            &[target(0.05), target(3.75)],
            0.12,
            &PosesOptions {
                max_keyframes: 6,
                ..PosesOptions::default()
            },
        );
        assert_eq!(capped.len(), 6, "the budget holds with bridges: {capped:?}");
    }

    #[test]
    fn rgb_views_are_the_track_keys_held_out_around_held_out_thermal_views() {
        // RGB at 10 Hz; keys (posed) at every frame but 4 and 12.
        let rgb = frames(&[1.0; 20], &[]);
        let pose = |t: u64| {
            Rigid3::new(
                glam::DQuat::from_rotation_y(t as f64 * 1e-9),
                DVec3::new(t as f64 * 1e-9, 0.0, 0.0),
            )
        };
        let keys: Vec<(u64, Rigid3)> = rgb
            .iter()
            .filter(|f| f.sequence != 4 && f.sequence != 12)
            .map(|f| (f.monotonic_ns, pose(f.monotonic_ns)))
            .collect();
        let track = Track::new(&keys, 0.26);
        let thermal = |t_s: f64, held_out: bool| ThermalView {
            sequence: 0,
            monotonic_ns: (t_s * 1e9) as u64,
            world_from_cam: Rigid3::IDENTITY,
            held_out,
        };
        // Held out at 0.43 s (RGB 0.4 and 0.5 within 0.12 s; 0.4 is not posed) and at 1.2 s
        // (not posed: 1.1 and 1.3 within 0.12 s); 0.9 s trains.
        let views = rgb_views(
            &track,
            &rgb,
            &[thermal(0.43, true), thermal(0.9, false), thermal(1.2, true)],
            0.12,
        );
        assert_eq!(views.len(), 18, "one view per posed keyframe");
        assert!(
            views
                .iter()
                .all(|v| v.world_from_cam == pose(v.monotonic_ns)
                    && u64::from(v.sequence) * 100_000_000 == v.monotonic_ns),
            "the keys' own poses, named by their frames"
        );
        let held: Vec<u32> = views
            .iter()
            .filter(|v| v.held_out)
            .map(|v| v.sequence)
            .collect();
        assert_eq!(held, vec![5, 11, 13]);
        // A window of 0: the nearest one only.
        let nearest = rgb_views(&track, &rgb, &[thermal(0.43, true)], 0.0);
        let held: Vec<u32> = nearest
            .iter()
            .filter(|v| v.held_out)
            .map(|v| v.sequence)
            .collect();
        assert_eq!(held, vec![5]);
    }

    #[test]
    fn candidates_say_why_each_frame_was_left_out() {
        let mut s = vec![1.0; 20];
        s[3] = 0.1;
        let opts = PosesOptions {
            thermal_hz: 4.0,
            ..PosesOptions::default()
        };
        let (c, why) = thermal_candidates(&frames(&s, &[7]), &opts);
        assert_eq!(c.len() + why.len(), 20, "every frame accounted for");
        let reason = |q: u32| {
            why.iter()
                .find(|d| d.sequence == q)
                .map(|d| d.decision.clone())
        };
        assert_eq!(reason(3).as_deref(), Some("skipped: motion-blurred"));
        assert_eq!(reason(7).as_deref(), Some("skipped: FFC-frozen"));
        assert_eq!(c.len(), 8, "2 s at 4 Hz");
    }
}
