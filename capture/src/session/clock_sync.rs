//! Rig-controller clock → camera clock.
//!
//! The rig controller stamps its trigger pulses on its own free-running clock (an unknown
//! offset from the host and a crystal drift of tens of ppm); cameras stamp frames on the host's
//! `CLOCK_MONOTONIC`. A frame exposed by pulse `k` is matched to it by time (its stamp nearest
//! the pulse's mapped time, within a tolerance), and a straight line
//! `monotonic_ns = mono_anchor_ns + slope · (controller_ns − controller_anchor_ns)` is fitted
//! robustly over the matched (pulse, frame) pairs: least squares, then points further than
//! 5 robust σ (1.4826 · MAD of the residuals, at least 20 µs) from the line are dropped and
//! the line refitted, three times. The residual of the kept points is the sync residual `info`
//! reports: camera latency jitter plus stamp noise.
//!
//! Before any pulse has been matched, a rough map comes from one GetStatus exchange: the
//! controller's uptime at the midpoint of the request/reply on the host clock (error ≤ half
//! the round trip, ~1 ms on a serial port, far below half a trigger period).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::error::CaptureError;
use crate::frame::StreamKind;
use crate::session::PairRecord;

/// A linear map from controller time to camera (host monotonic) time, with its fit quality.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClockMap {
    pub controller_anchor_ns: u64,
    pub mono_anchor_ns: u64,
    /// d(monotonic) / d(controller).
    pub slope: f64,
    /// How fast the controller clock runs against the camera clock, ppm (`1/slope − 1`).
    pub drift_ppm: f64,
    /// Points used in the fit (after outlier rejection), and those rejected.
    pub matched: u64,
    pub outliers: u64,
    /// RMS and largest absolute residual of the kept points, nanoseconds.
    pub residual_rms_ns: f64,
    pub residual_max_ns: f64,
}

impl ClockMap {
    /// A map with slope 1 through one (controller, monotonic) correspondence.
    pub fn rough(controller_ns: u64, mono_ns: u64) -> Self {
        Self {
            controller_anchor_ns: controller_ns,
            mono_anchor_ns: mono_ns,
            slope: 1.0,
            drift_ppm: 0.0,
            matched: 0,
            outliers: 0,
            // Unknown until fitted; `matched == 0` marks a rough map.
            residual_rms_ns: 0.0,
            residual_max_ns: 0.0,
        }
    }

    /// Camera-clock time of a controller time.
    pub fn to_mono_ns(&self, controller_ns: u64) -> i128 {
        let dc = controller_ns as f64 - self.controller_anchor_ns as f64;
        i128::from(self.mono_anchor_ns) + (self.slope * dc).round() as i128
    }
}

/// Fits a [`ClockMap`] to (controller_ns, monotonic_ns) points (see the module doc).
pub fn fit(points: &[(u64, u64)]) -> Result<ClockMap, CaptureError> {
    if points.len() < 3 {
        return Err(CaptureError::ClockFit {
            reason: format!("{} matched trigger pulses, need at least 3", points.len()),
        });
    }
    // Work relative to the first point in f64 (sessions are hours at most: < 2⁵³ ns).
    let (c0, m0) = points[0];
    let xy: Vec<(f64, f64)> = points
        .iter()
        .map(|&(c, m)| (c as f64 - c0 as f64, m as f64 - m0 as f64))
        .collect();
    let mut keep = vec![true; xy.len()];
    let mut line = (0.0, 1.0);
    for _ in 0..4 {
        line = least_squares(&xy, &keep).ok_or_else(|| CaptureError::ClockFit {
            reason: "trigger pulses span no time".into(),
        })?;
        let res: Vec<f64> = xy.iter().map(|&(x, y)| y - (line.0 + line.1 * x)).collect();
        let mut abs: Vec<f64> = res
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(r, _)| r.abs())
            .collect();
        abs.sort_by(f64::total_cmp);
        let mad = abs.get(abs.len() / 2).copied().unwrap_or(0.0);
        let limit = (5.0 * 1.4826 * mad).max(20_000.0);
        let next: Vec<bool> = res.iter().map(|r| r.abs() <= limit).collect();
        if next.iter().filter(|k| **k).count() < 3 || next == keep {
            break;
        }
        keep = next;
    }
    let (a, b) = line;
    let kept: Vec<f64> = xy
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(&(x, y), _)| y - (a + b * x))
        .collect();
    let n = kept.len();
    let rms = (kept.iter().map(|r| r * r).sum::<f64>() / n as f64).sqrt();
    let max = kept.iter().fold(0.0f64, |m, r| m.max(r.abs()));
    Ok(ClockMap {
        controller_anchor_ns: c0,
        mono_anchor_ns: (m0 as f64 + a).round() as u64,
        slope: b,
        drift_ppm: (1.0 / b - 1.0) * 1e6,
        matched: n as u64,
        outliers: (points.len() - n) as u64,
        residual_rms_ns: rms,
        residual_max_ns: max,
    })
}

/// Intercept and slope of the least-squares line through the kept points.
fn least_squares(xy: &[(f64, f64)], keep: &[bool]) -> Option<(f64, f64)> {
    let pts = xy.iter().zip(keep).filter(|(_, k)| **k).map(|(p, _)| *p);
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (x, y) in pts.clone() {
        n += 1.0;
        sx += x;
        sy += y;
    }
    if n < 2.0 {
        return None;
    }
    let (mx, my) = (sx / n, sy / n);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (x, y) in pts {
        sxx += (x - mx) * (x - mx);
        sxy += (x - mx) * (y - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let b = sxy / sxx;
    Some((my - b * mx, b))
}

/// The pulse (count) whose mapped time is nearest `frame_mono_ns`, when within `tolerance_ns`.
/// `pulses` are (count, controller_ns) in increasing time.
pub fn nearest_pulse(
    map: &ClockMap,
    pulses: &[(u32, u64)],
    frame_mono_ns: u64,
    tolerance_ns: u64,
) -> Option<(u32, u64)> {
    let t = i128::from(frame_mono_ns);
    let i = pulses.partition_point(|&(_, c)| map.to_mono_ns(c) < t);
    [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|j| pulses.get(j).copied())
        .map(|p| (p, (map.to_mono_ns(p.1) - t).unsigned_abs()))
        .filter(|(_, d)| *d <= u128::from(tolerance_ns))
        .min_by_key(|(_, d)| *d)
        .map(|(p, _)| p)
}

/// Output of a [`TriggerPairer`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TriggerOutput {
    Pair(PairRecord),
    /// The clock map was refitted.
    Clock(ClockMap),
}

#[derive(Debug, Clone, Copy)]
struct PendingFrame {
    stream: StreamKind,
    sequence: u32,
    t_ns: u64,
    frozen: bool,
}

/// Most recent pulses and matched points kept (minutes at trigger rates).
const MAX_PULSES: usize = 4096;
const MAX_POINTS: usize = 4096;
/// Frames waiting for a later pulse; beyond this (a controller that stopped answering) the
/// oldest are decided with the pulses known, so memory stays bounded.
const MAX_PENDING: usize = 2048;

/// Pairs frames by trigger pulse: each frame is matched to the pulse whose mapped time is
/// nearest its stamp (within half the pulse period) once a later pulse has been seen (so no
/// nearer one can still come); thermal matches feed the clock fit, which is redone as points
/// accumulate; a thermal and an RGB frame of the same pulse are a pair. FFC-frozen thermal
/// frames are matched (their stamps are real) but never paired. Deterministic in its input
/// order (frames and pulses as recorded), so replay reproduces it.
#[derive(Debug, Clone, Default)]
pub struct TriggerPairer {
    map: Option<ClockMap>,
    pulses: Vec<(u32, u64)>,
    pending: std::collections::VecDeque<PendingFrame>,
    points: std::collections::VecDeque<(u64, u64)>,
    new_points: usize,
    by_count: [BTreeMap<u32, (u32, u64)>; 2],
    /// Frames matched to a pulse / not matched to any.
    pub matched: u64,
    pub unmatched: u64,
}

impl TriggerPairer {
    /// Starts from a rough map ([`ClockMap::rough`]).
    pub fn new(rough: ClockMap) -> Self {
        Self {
            map: Some(rough),
            ..Self::default()
        }
    }

    /// The current map (rough until the first fit).
    pub fn map(&self) -> Option<ClockMap> {
        self.map
    }

    /// Half the pulse period (from the last two pulses), the matching tolerance.
    fn tolerance_ns(&self) -> Option<u64> {
        let n = self.pulses.len();
        if n < 2 {
            return None;
        }
        let (c0, t0) = self.pulses[n - 2];
        let (c1, t1) = self.pulses[n - 1];
        let k = u64::from(c1.wrapping_sub(c0)).max(1);
        Some(t1.saturating_sub(t0) / k / 2)
    }

    pub fn push_frame(
        &mut self,
        stream: StreamKind,
        sequence: u32,
        t_ns: u64,
        frozen: bool,
    ) -> Vec<TriggerOutput> {
        self.pending.push_back(PendingFrame {
            stream,
            sequence,
            t_ns,
            frozen,
        });
        self.resolve(false)
    }

    pub fn push_pulse(&mut self, count: u32, controller_ns: u64) -> Vec<TriggerOutput> {
        if self
            .pulses
            .last()
            .is_some_and(|&(c, t)| (count.wrapping_sub(c) as i32) <= 0 || controller_ns <= t)
        {
            return Vec::new();
        }
        self.pulses.push((count, controller_ns));
        if self.pulses.len() > 2 * MAX_PULSES {
            self.pulses.drain(..MAX_PULSES);
        }
        self.resolve(false)
    }

    /// Decides every frame still waiting (end of recording).
    pub fn finish(&mut self) -> Vec<TriggerOutput> {
        self.resolve(true)
    }

    fn resolve(&mut self, all: bool) -> Vec<TriggerOutput> {
        let mut out = Vec::new();
        while let Some(&f) = self.pending.front() {
            let tol = self.tolerance_ns();
            let decidable = all
                || self.pending.len() > MAX_PENDING
                || match (self.map, tol, self.pulses.last()) {
                    (Some(m), Some(tol), Some(&(_, last))) => {
                        m.to_mono_ns(last) > i128::from(f.t_ns) + i128::from(tol)
                    }
                    _ => false,
                };
            if !decidable {
                break;
            }
            self.pending.pop_front();
            let hit = match (self.map, tol) {
                (Some(m), Some(tol)) => nearest_pulse(&m, &self.pulses, f.t_ns, tol),
                _ => None,
            };
            let Some((count, controller_ns)) = hit else {
                self.unmatched += 1;
                continue;
            };
            self.matched += 1;
            let k = usize::from(f.stream == StreamKind::Rgb);
            if k == 0 {
                self.points.push_back((controller_ns, f.t_ns));
                if self.points.len() > MAX_POINTS {
                    self.points.pop_front();
                }
                self.new_points += 1;
                // Refit often while the fit is young, then every ~second at 30 Hz.
                if self.new_points >= (self.points.len() / 8).clamp(8, 30) {
                    self.new_points = 0;
                    let pts: Vec<(u64, u64)> = self.points.iter().copied().collect();
                    if let Ok(m) = fit(&pts) {
                        self.map = Some(m);
                        out.push(TriggerOutput::Clock(m));
                    }
                }
            }
            if k == 0 && f.frozen {
                continue;
            }
            if let Some((seq, t)) = self.by_count[1 - k].remove(&count) {
                let (th, rg) = if k == 0 {
                    ((f.sequence, f.t_ns), (seq, t))
                } else {
                    ((seq, t), (f.sequence, f.t_ns))
                };
                out.push(TriggerOutput::Pair(PairRecord {
                    thermal_sequence: th.0,
                    rgb_sequence: rg.0,
                    thermal_monotonic_ns: th.1,
                    rgb_monotonic_ns: rg.1,
                    sync_error_ns: th.1 as i64 - rg.1 as i64,
                }));
            } else {
                self.by_count[k].insert(count, (f.sequence, f.t_ns));
                while self.by_count[k].len() > 256 {
                    self.by_count[k].pop_first();
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    //! Proves: the robust fit recovers a known offset and drift from jittered points with
    //! outliers (residual ≈ the jitter), rejects too few points, and pulse matching picks the
    //! nearest pulse within tolerance only. Does not use a real controller (the end-to-end test
    //! tests/tests/capture_rig_trigger.rs does, against the simulated one).
    #![allow(clippy::unwrap_used)]
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn fit_recovers_offset_and_drift_and_rejects_outliers() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let drift_ppm = 37.0;
        let offset = 5_000_000_000i64;
        let mut pts = Vec::new();
        for k in 0..600u64 {
            let c = 123_456_789_000 + k * 33_333_333;
            // mono = offset + c / (1 + drift): the controller runs fast.
            let ideal = offset as f64 + c as f64 / (1.0 + drift_ppm * 1e-6);
            let jitter = rng.random_range(-25_000.0..25_000.0);
            let outlier = if k % 97 == 5 { 3_000_000.0 } else { 0.0 };
            pts.push((c, (ideal + jitter + outlier).round() as u64));
        }
        let m = fit(&pts).unwrap();
        assert!(
            (m.drift_ppm - drift_ppm).abs() < 0.5,
            "drift {} ppm, want {drift_ppm}",
            m.drift_ppm
        );
        assert_eq!(m.outliers, 7, "7 points were 3 ms off: {m:?}");
        // Uniform ±25 µs has σ = 14.4 µs.
        assert!(
            (10_000.0..19_000.0).contains(&m.residual_rms_ns),
            "residual rms {} ns, want ≈ 14 400",
            m.residual_rms_ns
        );
        assert!(
            m.residual_max_ns <= 30_000.0,
            "max residual {} ns: the ±25 µs jitter plus the fitted line's own error",
            m.residual_max_ns
        );
        let c = 123_456_789_000 + 300 * 33_333_333u64;
        let want = offset as f64 + c as f64 / (1.0 + drift_ppm * 1e-6);
        let got = m.to_mono_ns(c) as f64;
        assert!((got - want).abs() < 5_000.0, "mapped {got}, want {want}");
    }

    #[test]
    fn fit_needs_three_points_spanning_time() {
        assert!(fit(&[(1, 1), (2, 2)]).is_err());
        assert!(fit(&[(5, 1), (5, 2), (5, 3)]).is_err());
    }

    #[test]
    fn nearest_pulse_within_tolerance_only() {
        let map = ClockMap::rough(1_000, 10_000);
        let pulses = [(7, 1_000), (8, 34_333_333), (9, 67_666_666)];
        assert_eq!(
            nearest_pulse(&map, &pulses, 10_000 + 34_333_000, 1_000_000),
            Some((8, 34_333_333))
        );
        assert_eq!(nearest_pulse(&map, &pulses, 10_000, 10), Some((7, 1_000)));
        assert_eq!(
            nearest_pulse(&map, &pulses, 10_000 + 17_000_000, 1_000_000),
            None,
            "half-way between pulses: no match"
        );
        assert_eq!(nearest_pulse(&map, &[], 5, 1_000_000), None);
    }

    #[test]
    fn trigger_pairer_pairs_by_pulse_fits_the_clock_and_skips_frozen_frames() {
        let drift = 37e-6;
        let period_c = 33_333_333u64;
        let c_of = |k: u64| 1_000_000_000_000 + k * period_c;
        let mono_of = |c: u64| 2_000_000_000 + ((c - c_of(0)) as f64 / (1.0 + drift)) as u64;
        // Rough map 2 ms off: still far inside half a period.
        let mut p = TriggerPairer::new(ClockMap::rough(c_of(0), mono_of(c_of(0)) + 2_000_000));
        let mut pairs = Vec::new();
        let mut clocks = Vec::new();
        let mut take = |o: Vec<TriggerOutput>| {
            for x in o {
                match x {
                    TriggerOutput::Pair(r) => pairs.push(r),
                    TriggerOutput::Clock(c) => clocks.push(c),
                }
            }
        };
        // A free-running frame before the trigger started: matched to nothing.
        take(p.push_frame(
            StreamKind::Thermal,
            99,
            mono_of(c_of(0)) - 500_000_000,
            false,
        ));
        for k in 0..300u64 {
            let m = mono_of(c_of(k));
            // Frames arrive before the pulse report (the poll lags); thermal 350 µs, RGB 120 µs.
            take(p.push_frame(StreamKind::Thermal, 100 + k as u32, m + 350_000, k == 50));
            if k != 77 {
                take(p.push_frame(StreamKind::Rgb, 10 + k as u32, m + 120_000, false));
            }
            take(p.push_pulse(500 + k as u32, c_of(k)));
        }
        take(p.finish());
        // 300 pulses, RGB missing at 77, thermal 50 frozen: 298 pairs.
        assert_eq!(pairs.len(), 298, "pairs");
        assert!(
            pairs
                .iter()
                .all(|r| r.thermal_sequence - 100 == r.rgb_sequence - 10)
        );
        assert!(
            pairs.iter().all(|r| r.sync_error_ns == 230_000),
            "latency difference"
        );
        assert_eq!(p.unmatched, 1, "the free-running frame");
        let last = clocks.last().unwrap();
        assert!(
            (last.drift_ppm - 37.0).abs() < 0.05,
            "drift {} ppm",
            last.drift_ppm
        );
        assert!(
            last.residual_rms_ns < 2.0,
            "no jitter: residual {}",
            last.residual_rms_ns
        );
        // The fitted map includes the thermal latency (the camera's stamp of pulse k).
        let k = 200;
        let got = last.to_mono_ns(c_of(k)) as i64 - (mono_of(c_of(k)) + 350_000) as i64;
        assert!(got.abs() < 5, "mapped pulse {k} off by {got} ns");
    }
}
