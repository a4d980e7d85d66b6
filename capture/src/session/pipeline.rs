//! The one path every frame takes, live or replayed: parse the device buffer, detect drops
//! from sequence gaps, pair, and emit the records a session holds.
//!
//! It is deterministic in its inputs (device buffers and their wall-clock stamps, in order),
//! which is what makes `s3tir-capture replay` reproduce a recording byte for byte.

use crate::error::CaptureError;
use crate::frame::{CapturedFrame, RawFrame, StreamKind};
use crate::session::clock_sync::{ClockMap, TriggerOutput, TriggerPairer};
use crate::session::pairing::{Pairer, PairingMode, SeqTracker, SyncAccumulator};
use crate::session::{SessionRecord, TriggerRecord};

/// Counters of one pipeline run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamCounts {
    pub frames: u64,
    pub drops: u64,
    pub ffc_frames: u64,
    pub rejected: u64,
}

/// Parse → drop detection → pairing.
#[derive(Debug, Clone)]
pub struct Pipeline {
    trackers: [SeqTracker; 2],
    pairer: Pairer,
    pub thermal: StreamCounts,
    pub rgb: StreamCounts,
    pub pairs: u64,
    pub sync: SyncAccumulator,
    /// Pairing by trigger pulse through the controller-clock map, once a rough map is given
    /// ([`Pipeline::set_rough_clock`]); until then (and without a rig controller) `pairer`.
    trigger: Option<TriggerPairer>,
}

impl Pipeline {
    pub fn new(mode: PairingMode) -> Self {
        Self {
            trackers: [
                SeqTracker::new(StreamKind::Thermal),
                SeqTracker::new(StreamKind::Rgb),
            ],
            pairer: Pairer::new(mode),
            thermal: StreamCounts::default(),
            rgb: StreamCounts::default(),
            pairs: 0,
            sync: SyncAccumulator::default(),
            trigger: None,
        }
    }

    /// The rig controller triggers the cameras: pair frames by trigger pulse from now on,
    /// starting from this rough controller → camera clock map. Returns the record to write
    /// (replay feeds the recorded one back here).
    pub fn set_rough_clock(&mut self, rough: ClockMap) -> Vec<SessionRecord> {
        self.trigger = Some(TriggerPairer::new(rough));
        vec![SessionRecord::Clock(rough)]
    }

    /// The current controller → camera clock map, when triggering.
    pub fn clock(&self) -> Option<ClockMap> {
        self.trigger.as_ref().and_then(TriggerPairer::map)
    }

    /// Pushes one rig-controller trigger pulse (ignored without a rough clock: nothing to
    /// map it with, but it is still recorded).
    pub fn push_trigger(&mut self, t: TriggerRecord) -> Vec<SessionRecord> {
        let mut out = vec![SessionRecord::Trigger(t)];
        if let Some(tp) = self.trigger.as_mut() {
            let o = tp.push_pulse(t.count, t.controller_ns);
            self.take_trigger_outputs(o, &mut out);
        }
        out
    }

    fn take_trigger_outputs(&mut self, o: Vec<TriggerOutput>, out: &mut Vec<SessionRecord>) {
        for x in o {
            match x {
                TriggerOutput::Pair(p) => {
                    self.pairs += 1;
                    self.sync.add(p.sync_error_ns);
                    out.push(SessionRecord::Pair(p));
                }
                TriggerOutput::Clock(c) => out.push(SessionRecord::Clock(c)),
            }
        }
    }

    /// Pushes one device buffer. A buffer that does not parse is counted as rejected and
    /// returned as the error (nothing is recorded for it, and it does not advance drop
    /// detection: the sequence gap it leaves is reported as a drop by the next good frame).
    pub fn push(
        &mut self,
        device: &str,
        raw: &RawFrame,
        wall_unix_ns: u64,
    ) -> Result<Vec<SessionRecord>, CaptureError> {
        let (k, counts) = match raw.stream {
            StreamKind::Thermal => (0, &mut self.thermal),
            StreamKind::Rgb => (1, &mut self.rgb),
        };
        let frame = match CapturedFrame::from_raw(device, raw, wall_unix_ns) {
            Ok(f) => f,
            Err(e) => {
                counts.rejected += 1;
                return Err(e);
            }
        };
        let mut out = Vec::with_capacity(3);
        if let Some(d) = self.trackers[k].push(raw.sequence, raw.monotonic_ns) {
            counts.drops += u64::from(d.missing);
            out.push(SessionRecord::Drop(d));
        }
        counts.frames += 1;
        let frozen = matches!(&frame, CapturedFrame::Thermal(t) if t.is_ffc_frozen());
        if frozen {
            counts.ffc_frames += 1;
        }
        out.push(SessionRecord::Frame {
            frame,
            ffc_hint: raw.ffc_hint,
        });
        if let Some(tp) = self.trigger.as_mut() {
            let o = tp.push_frame(raw.stream, raw.sequence, raw.monotonic_ns, frozen);
            self.take_trigger_outputs(o, &mut out);
            return Ok(out);
        }
        let pairs = self
            .pairer
            .push(raw.stream, raw.sequence, raw.monotonic_ns, frozen);
        for p in pairs {
            self.pairs += 1;
            self.sync.add(p.sync_error_ns);
            out.push(SessionRecord::Pair(p));
        }
        Ok(out)
    }

    /// Decides the frames still waiting for a partner (end of recording).
    pub fn finish(&mut self) -> Vec<SessionRecord> {
        if let Some(tp) = self.trigger.as_mut() {
            let o = tp.finish();
            let mut out = Vec::new();
            self.take_trigger_outputs(o, &mut out);
            return out;
        }
        self.pairer
            .finish()
            .into_iter()
            .map(|p| {
                self.pairs += 1;
                self.sync.add(p.sync_error_ns);
                SessionRecord::Pair(p)
            })
            .collect()
    }
}
