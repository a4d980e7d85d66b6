//! Thermal↔RGB pairing, sequence-gap drop detection and sync-error statistics.
//!
//! Two modes:
//! - [`PairingMode::Nearest`]: each RGB frame is paired with the thermal frame nearest in
//!   `monotonic_ns` within a tolerance, each frame used at most once. It is decided online as
//!   soon as a thermal frame later than `rgb + tolerance` has arrived (no later thermal frame can
//!   then be within tolerance), so the pairing is a pure function of the frame order, which is
//!   what makes replay reproduce it exactly.
//! - [`PairingMode::TriggerCounter`]: when the rig controller triggers both cameras, frame `k`
//!   after the first of each stream came from trigger pulse `k`; pairs share the pulse index
//!   `sequence − first_sequence` (gaps from drops keep the indices aligned).
//!
//! FFC-frozen thermal frames are recorded but never paired (in both modes).

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};

use crate::frame::StreamKind;

/// A thermal↔RGB pair (`/pairs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PairRecord {
    pub thermal_sequence: u32,
    pub rgb_sequence: u32,
    pub thermal_monotonic_ns: u64,
    pub rgb_monotonic_ns: u64,
    /// `thermal − rgb` capture time, nanoseconds.
    pub sync_error_ns: i64,
}

/// A sequence gap (`/drops`): `missing` frames between `after_sequence` and the next one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DropRecord {
    pub stream: StreamKind,
    pub after_sequence: u32,
    pub missing: u32,
    pub monotonic_ns: u64,
}

/// Default pairing tolerance: half a 60 Hz frame period.
pub const DEFAULT_TOLERANCE_NS: u64 = 8_000_000;

/// How frames are paired.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairingMode {
    Nearest { tolerance_ns: u64 },
    TriggerCounter,
}

impl std::fmt::Display for PairingMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PairingMode::Nearest { tolerance_ns } => {
                write!(f, "nearest within {:.3} ms", *tolerance_ns as f64 / 1e6)
            }
            PairingMode::TriggerCounter => f.write_str("trigger counter"),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Pending {
    sequence: u32,
    t_ns: u64,
}

/// How long a frame waits for its partner stream before it is decided without it (pending
/// queues stay bounded when one camera stops). Far above any delivery lag between the two
/// streams (tens of ms).
pub const PAIR_HORIZON_NS: u64 = 2_000_000_000;

/// Online pairer. Feed frames in arrival order; it returns pairs as they are decided.
#[derive(Debug, Clone)]
pub struct Pairer {
    mode: PairingMode,
    thermal: VecDeque<Pending>,
    rgb: VecDeque<Pending>,
    latest_thermal_ns: Option<u64>,
    first_seq: [Option<u32>; 2],
    by_index: [BTreeMap<u32, Pending>; 2],
}

impl Pairer {
    pub fn new(mode: PairingMode) -> Self {
        Self {
            mode,
            thermal: VecDeque::new(),
            rgb: VecDeque::new(),
            latest_thermal_ns: None,
            first_seq: [None, None],
            by_index: [BTreeMap::new(), BTreeMap::new()],
        }
    }

    pub fn mode(&self) -> PairingMode {
        self.mode
    }

    /// Adds a frame; `ffc_frozen` thermal frames are never paired.
    pub fn push(
        &mut self,
        stream: StreamKind,
        sequence: u32,
        t_ns: u64,
        ffc_frozen: bool,
    ) -> Vec<PairRecord> {
        match self.mode {
            PairingMode::Nearest { tolerance_ns } => {
                let p = Pending { sequence, t_ns };
                match stream {
                    StreamKind::Thermal => {
                        self.latest_thermal_ns =
                            Some(self.latest_thermal_ns.map_or(t_ns, |l| l.max(t_ns)));
                        if !ffc_frozen {
                            self.thermal.push_back(p);
                        }
                    }
                    StreamKind::Rgb => self.rgb.push_back(p),
                }
                self.resolve(tolerance_ns, false)
            }
            PairingMode::TriggerCounter => {
                let k = match stream {
                    StreamKind::Thermal => 0,
                    StreamKind::Rgb => 1,
                };
                let first = *self.first_seq[k].get_or_insert(sequence);
                let index = sequence.wrapping_sub(first);
                if stream == StreamKind::Thermal && ffc_frozen {
                    return Vec::new();
                }
                let other = 1 - k;
                let mut out = Vec::new();
                if let Some(o) = self.by_index[other].remove(&index) {
                    let me = Pending { sequence, t_ns };
                    let (th, rg) = if k == 0 { (me, o) } else { (o, me) };
                    out.push(pair(th, rg));
                } else {
                    self.by_index[k].insert(index, Pending { sequence, t_ns });
                }
                // Bound memory: forget indices far behind.
                for m in &mut self.by_index {
                    while m.len() > 256 {
                        m.pop_first();
                    }
                }
                out
            }
        }
    }

    /// Decides every pending frame (end of recording).
    pub fn finish(&mut self) -> Vec<PairRecord> {
        match self.mode {
            PairingMode::Nearest { tolerance_ns } => self.resolve(tolerance_ns, true),
            PairingMode::TriggerCounter => Vec::new(),
        }
    }

    fn resolve(&mut self, tol: u64, all: bool) -> Vec<PairRecord> {
        let mut out = Vec::new();
        // Bounded queues when one stream stops: a thermal frame older than the newest by more
        // than the horizon can only pair with an RGB frame that late, and an RGB frame older
        // than the newest RGB by the horizon is decided with the thermal frames there are.
        if let Some(latest) = self.latest_thermal_ns {
            while self
                .thermal
                .front()
                .is_some_and(|t| t.t_ns.saturating_add(PAIR_HORIZON_NS) < latest)
            {
                self.thermal.pop_front();
            }
        }
        let latest_rgb = self.rgb.back().map(|r| r.t_ns);
        while let Some(&r) = self.rgb.front() {
            let decidable = all
                || self
                    .latest_thermal_ns
                    .is_some_and(|l| l > r.t_ns.saturating_add(tol))
                || latest_rgb.is_some_and(|l| r.t_ns.saturating_add(PAIR_HORIZON_NS) < l);
            if !decidable {
                break;
            }
            self.rgb.pop_front();
            // Thermal frames too old for this (and so every later) RGB frame.
            while self
                .thermal
                .front()
                .is_some_and(|t| t.t_ns.saturating_add(tol) < r.t_ns)
            {
                self.thermal.pop_front();
            }
            let best = self
                .thermal
                .iter()
                .enumerate()
                .filter(|(_, t)| t.t_ns.abs_diff(r.t_ns) <= tol)
                .min_by_key(|(_, t)| t.t_ns.abs_diff(r.t_ns))
                .map(|(i, _)| i);
            if let Some(i) = best
                && let Some(t) = self.thermal.remove(i)
            {
                out.push(pair(t, r));
            }
        }
        out
    }
}

fn pair(t: Pending, r: Pending) -> PairRecord {
    PairRecord {
        thermal_sequence: t.sequence,
        rgb_sequence: r.sequence,
        thermal_monotonic_ns: t.t_ns,
        rgb_monotonic_ns: r.t_ns,
        sync_error_ns: t.t_ns as i64 - r.t_ns as i64,
    }
}

/// Detects dropped frames from sequence gaps of one stream, and across a device reopen by
/// time: a reopened V4L2 device restarts its sequence numbers at 0, so when the sequence goes
/// backwards the frames missing in between are estimated from the monotonic stamps (gap over
/// the stream's frame period, learnt from consecutive frames) rather than ignored.
#[derive(Debug, Clone)]
pub struct SeqTracker {
    stream: StreamKind,
    last: Option<(u32, u64)>,
    /// Running estimate of the frame period from sequence-consecutive frames, ns.
    period_ns: Option<f64>,
    pub dropped: u64,
    /// Sequence restarts seen (device reopened).
    pub restarts: u64,
}

impl SeqTracker {
    pub fn new(stream: StreamKind) -> Self {
        Self {
            stream,
            last: None,
            period_ns: None,
            dropped: 0,
            restarts: 0,
        }
    }

    /// Feeds the next frame; a gap yields a drop record: by sequence normally, by time when
    /// the sequence went backwards (device reopened after a reconnect or a stall).
    pub fn push(&mut self, sequence: u32, monotonic_ns: u64) -> Option<DropRecord> {
        let (last, last_ns) = self.last.replace((sequence, monotonic_ns))?;
        let missing = if sequence > last {
            let steps = sequence - last;
            if monotonic_ns > last_ns {
                let dt = (monotonic_ns - last_ns) as f64 / f64::from(steps);
                self.period_ns = Some(self.period_ns.map_or(dt, |p| 0.9 * p + 0.1 * dt));
            }
            steps - 1
        } else {
            self.restarts += 1;
            match self.period_ns {
                Some(p) if p > 0.0 && monotonic_ns > last_ns => {
                    let frames = ((monotonic_ns - last_ns) as f64 / p).round();
                    (frames - 1.0).clamp(0.0, f64::from(u32::MAX)) as u32
                }
                _ => 0,
            }
        };
        if missing == 0 {
            return None;
        }
        self.dropped += u64::from(missing);
        Some(DropRecord {
            stream: self.stream,
            after_sequence: last,
            missing,
            monotonic_ns,
        })
    }
}

/// Sync-error statistics over pairs (`thermal − rgb` capture time).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SyncStats {
    pub pairs: u64,
    pub mean_ns: f64,
    pub rms_ns: f64,
    pub max_abs_ns: u64,
}

/// Accumulates [`SyncStats`].
#[derive(Debug, Clone, Copy, Default)]
pub struct SyncAccumulator {
    n: u64,
    sum: f64,
    sum_sq: f64,
    max_abs: u64,
}

impl SyncAccumulator {
    pub fn add(&mut self, sync_error_ns: i64) {
        self.n += 1;
        let e = sync_error_ns as f64;
        self.sum += e;
        self.sum_sq += e * e;
        self.max_abs = self.max_abs.max(sync_error_ns.unsigned_abs());
    }

    pub fn stats(&self) -> SyncStats {
        if self.n == 0 {
            return SyncStats::default();
        }
        let n = self.n as f64;
        SyncStats {
            pairs: self.n,
            mean_ns: self.sum / n,
            rms_ns: (self.sum_sq / n).sqrt(),
            max_abs_ns: self.max_abs,
        }
    }
}

#[cfg(test)]
mod tests {
    //! Proves: nearest pairing picks the closest thermal frame within tolerance, never uses an
    //! FFC-frozen one or a frame twice, and is decided online; trigger pairing aligns pulse
    //! indices across drops; drop detection counts gaps. Does not measure real clock skew.
    #![allow(clippy::unwrap_used)]
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn nearest_pairs_closest_and_skips_ffc_frozen() {
        let mut p = Pairer::new(PairingMode::Nearest {
            tolerance_ns: 10 * MS,
        });
        let mut pairs = Vec::new();
        // thermal at 60 Hz-ish: 0, 16, 33, 50 ms; rgb at 0+3, 33+2 ms.
        pairs.extend(p.push(StreamKind::Thermal, 0, 0, false));
        pairs.extend(p.push(StreamKind::Rgb, 100, 3 * MS, false));
        pairs.extend(p.push(StreamKind::Thermal, 1, 16 * MS, false));
        pairs.extend(p.push(StreamKind::Rgb, 101, 35 * MS, false));
        pairs.extend(p.push(StreamKind::Thermal, 2, 33 * MS, true)); // frozen
        pairs.extend(p.push(StreamKind::Thermal, 3, 50 * MS, false));
        pairs.extend(p.finish());
        assert_eq!(
            pairs.len(),
            1,
            "rgb 101's nearest is frozen, next is 15 ms away: {pairs:?}"
        );
        assert_eq!((pairs[0].thermal_sequence, pairs[0].rgb_sequence), (0, 100));
        assert_eq!(pairs[0].sync_error_ns, -3 * MS as i64);
    }

    #[test]
    fn nearest_waits_for_a_possibly_closer_frame() {
        let mut p = Pairer::new(PairingMode::Nearest {
            tolerance_ns: 10 * MS,
        });
        assert!(p.push(StreamKind::Thermal, 0, 0, false).is_empty());
        assert!(
            p.push(StreamKind::Rgb, 7, 6 * MS, false).is_empty(),
            "undecided until a thermal frame past 16 ms"
        );
        assert!(p.push(StreamKind::Thermal, 1, 8 * MS, false).is_empty());
        let out = p.push(StreamKind::Thermal, 2, 20 * MS, false);
        assert_eq!(out.len(), 1);
        assert_eq!(
            out[0].thermal_sequence, 1,
            "8 ms is nearer to 6 ms than 0 ms"
        );
    }

    #[test]
    fn trigger_mode_aligns_indices_across_drops() {
        let mut p = Pairer::new(PairingMode::TriggerCounter);
        let mut pairs = Vec::new();
        for (s, t) in [(10u32, 0u64), (11, 1), (13, 3)] {
            pairs.extend(p.push(StreamKind::Thermal, s, t, false));
        }
        for (s, t) in [(500u32, 0u64), (502, 2), (503, 3)] {
            pairs.extend(p.push(StreamKind::Rgb, s, t, false));
        }
        let got: Vec<_> = pairs
            .iter()
            .map(|p| (p.thermal_sequence, p.rgb_sequence))
            .collect();
        assert_eq!(got, vec![(10, 500), (13, 503)]);
    }

    #[test]
    fn gaps_are_counted_by_sequence_and_across_a_restart_by_time() {
        let mut t = SeqTracker::new(StreamKind::Thermal);
        // 60 Hz: one frame every 16.67 ms.
        let at = |k: u64| k * 16_666_667;
        assert!(t.push(5, at(5)).is_none());
        assert!(t.push(6, at(6)).is_none());
        let d = t.push(9, at(9)).unwrap();
        assert_eq!((d.after_sequence, d.missing), (6, 2));
        // The device is reopened 1 s (60 frame times) later with its sequence back at 0: the
        // 59 frames in between are drops, not nothing.
        let Some(d) = t.push(0, at(69)) else {
            panic!("the outage must be counted as drops");
        };
        assert_eq!((d.after_sequence, d.missing), (9, 59), "counted by time");
        assert!(t.push(1, at(70)).is_none());
        assert_eq!(t.dropped, 61);
        assert_eq!(t.restarts, 1);
        // A restart right away (no frame time passed) loses nothing.
        assert!(t.push(0, at(71)).is_none());
        // Before any period is known, a restart cannot be measured: nothing is invented.
        let mut fresh = SeqTracker::new(StreamKind::Rgb);
        fresh.push(3, 0);
        assert!(fresh.push(0, 1_000_000_000).is_none());
    }

    /// When one stream stops (an RGB camera unplugged, a stalled core), the other's pending
    /// frames are decided once they are older than the horizon: the queues stay bounded.
    #[test]
    fn pending_frames_stay_bounded_when_the_other_stream_stops() {
        let mut p = Pairer::new(PairingMode::Nearest {
            tolerance_ns: 10 * MS,
        });
        // 10 minutes of 60 Hz thermal, no RGB at all.
        for k in 0..36_000u64 {
            assert!(
                p.push(StreamKind::Thermal, k as u32, k * 16_666_667, false)
                    .is_empty()
            );
        }
        let horizon_frames = (PAIR_HORIZON_NS / 16_666_667 + 2) as usize;
        assert!(
            p.thermal.len() <= horizon_frames,
            "{} thermal frames pending, at most {horizon_frames} expected",
            p.thermal.len()
        );
        // And the other way round: RGB with the thermal core stalled.
        let mut p = Pairer::new(PairingMode::Nearest {
            tolerance_ns: 10 * MS,
        });
        p.push(StreamKind::Thermal, 0, 0, false);
        for k in 0..18_000u64 {
            p.push(
                StreamKind::Rgb,
                k as u32,
                1_000 * MS + k * 33_333_333,
                false,
            );
        }
        let horizon_frames = (PAIR_HORIZON_NS / 33_333_333 + 2) as usize;
        assert!(
            p.rgb.len() <= horizon_frames,
            "{} RGB frames pending, at most {horizon_frames} expected",
            p.rgb.len()
        );
        // Pairing resumes when both streams are back.
        let t0 = 1_000 * MS + 18_000 * 33_333_333;
        let mut pairs = Vec::new();
        for k in 0..10u64 {
            pairs.extend(p.push(
                StreamKind::Thermal,
                100 + k as u32,
                t0 + k * 33_333_333,
                false,
            ));
            pairs.extend(p.push(
                StreamKind::Rgb,
                50_000 + k as u32,
                t0 + k * 33_333_333 + MS,
                false,
            ));
        }
        pairs.extend(p.finish());
        assert_eq!(pairs.len(), 10, "pairs after the streams resume: {pairs:?}");
    }

    #[test]
    fn sync_stats() {
        let mut a = SyncAccumulator::default();
        for e in [-3, 3, -4, 4] {
            a.add(e);
        }
        let s = a.stats();
        assert_eq!(s.pairs, 4);
        assert!(s.mean_ns.abs() < 1e-9);
        assert!((s.rms_ns - 12.5f64.sqrt()).abs() < 1e-9, "rms {}", s.rms_ns);
        assert_eq!(s.max_abs_ns, 4);
    }
}
