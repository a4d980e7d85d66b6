//! When each stream's frames happen: free-running sequence pacing ([`Pacer`]) or one frame
//! per trigger pulse of the rig controller ([`StreamClock`]), and the lateness statistics
//! logged at exit ([`StreamStats`]).

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::firmware::{Shared, TRIGGER_JITTER_NS, lock};
use super::monotonic_ns;

/// Sequence pacing of one stream: frame `n` is due at `start + phase + n·period` and stamped
/// with the CLOCK_MONOTONIC time of that instant (the moment of exposure), whenever it is
/// actually sent. A stream that falls behind (a loaded machine) sends its late frames as soon
/// as it can, in order, and never skips a sequence number for being late: a sequence gap in
/// what a client receives is a frame the sensor model dropped (`drop_probability`) or one the
/// client failed to read in time, never simulator lateness. Lateness is counted instead and
/// logged at exit ([`StreamStats`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Pacer {
    pub(super) start: Instant,
    pub(super) start_mono_ns: u64,
    pub(super) period_ns: f64,
    pub(super) phase_ns: u64,
}

impl Pacer {
    fn offset_ns(&self, n: u64) -> u64 {
        self.phase_ns + (n as f64 * self.period_ns).round() as u64
    }

    fn due(&self, n: u64) -> Instant {
        self.start + Duration::from_nanos(self.offset_ns(n))
    }

    fn stamp_ns(&self, n: u64) -> u64 {
        self.start_mono_ns + self.offset_ns(n)
    }
}

/// When a stream's frames happen: free-running on its [`Pacer`], or, while the rig
/// controller's trigger runs, one frame per pulse, stamped at the pulse's host time plus the
/// camera's latency and jitter ([`TRIGGER_LATENCY_NS`]). When the trigger stops the stream
/// free-runs again from that moment.
#[derive(Debug)]
pub(super) struct StreamClock {
    pacer: Pacer,
    n_free: u64,
    /// The next pulse this camera exposes on (while triggered).
    next_pulse: Option<u32>,
    latency_ns: u64,
    jitter: ChaCha8Rng,
}

impl StreamClock {
    pub(super) fn new(pacer: Pacer, latency_ns: u64, seed: u64) -> Self {
        Self {
            pacer,
            n_free: 0,
            next_pulse: None,
            latency_ns,
            jitter: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Waits for the next frame and returns its stamp (CLOCK_MONOTONIC, ns); `None` when
    /// stopped (flag or duration) first. Records lateness in `stats`.
    pub(super) fn next(
        &mut self,
        shared: &Mutex<Shared>,
        stop: &AtomicBool,
        end: Option<Instant>,
        stats: &mut StreamStats,
    ) -> Option<u64> {
        loop {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            let now = Instant::now();
            if end.is_some_and(|e| now >= e) {
                return None;
            }
            let triggered = {
                let mut s = lock(shared);
                let now_mono = monotonic_ns();
                s.controller.update(now_mono);
                let c = &s.controller;
                if c.running {
                    let mut want = *self.next_pulse.get_or_insert(c.count.wrapping_add(1));
                    // A camera that fell out of the controller's log skips to its oldest pulse
                    // (those triggers were missed: no frames, like a camera too busy to
                    // re-arm).
                    if let Some(first) = c.events.front().map(|e| e.count)
                        && (want.wrapping_sub(first) as i32) < 0
                    {
                        want = first;
                    }
                    self.next_pulse = Some(want);
                    let wait_ns = c
                        .mono_ns(c.next_pulse_ctrl_ns)
                        .saturating_sub(now_mono)
                        .clamp(200_000, 20_000_000);
                    Some((c.pulse_mono_ns(want).map(|m| (want, m)), now_mono, wait_ns))
                } else {
                    None
                }
            };
            match triggered {
                Some((Some((count, pulse_mono)), now_mono, _)) => {
                    self.next_pulse = Some(count.wrapping_add(1));
                    let lag = Duration::from_nanos(now_mono.saturating_sub(pulse_mono));
                    stats.frames += 1;
                    stats.max_lag = stats.max_lag.max(lag);
                    let j = self.jitter.random_range(0..=2 * TRIGGER_JITTER_NS);
                    return Some(pulse_mono + self.latency_ns + j - TRIGGER_JITTER_NS);
                }
                Some((None, _, wait_ns)) => {
                    thread::sleep(Duration::from_nanos(wait_ns));
                    continue;
                }
                None => {}
            }
            if self.next_pulse.take().is_some() {
                // The trigger stopped: free-run again from now.
                self.pacer.start = now;
                self.pacer.start_mono_ns = monotonic_ns();
                self.n_free = 0;
            }
            let due = self.pacer.due(self.n_free);
            if now >= due {
                let lag = now - due;
                stats.frames += 1;
                stats.max_lag = stats.max_lag.max(lag);
                if lag.as_nanos() as f64 > self.pacer.period_ns {
                    stats.late += 1;
                }
                let stamp = self.pacer.stamp_ns(self.n_free);
                self.n_free += 1;
                return Some(stamp);
            }
            thread::sleep((due - now).min(Duration::from_millis(20)));
        }
    }
}

/// What one stream did, logged when `run` ends.
#[derive(Debug, Default, Clone, Copy)]
pub(super) struct StreamStats {
    frames: u64,
    /// Frames sent more than one period after they were due.
    late: u64,
    max_lag: Duration,
}

impl StreamStats {
    pub(super) fn log(&self, stream: &str) {
        tracing::info!(
            "{stream}: {} frames, {} sent more than a frame period late, max lag {:.1} ms",
            self.frames,
            self.late,
            self.max_lag.as_secs_f64() * 1e3
        );
    }
}
