//! The one path every frame takes, live or replayed: parse the device buffer, detect drops
//! from sequence gaps, pair, and emit the records a session holds.
//!
//! It is deterministic in its inputs (device buffers and their wall-clock stamps, in order),
//! which is what makes `s3tir-capture replay` reproduce a recording byte for byte.

use crate::error::CaptureError;
use crate::frame::{CapturedFrame, RawFrame, StreamKind};
use crate::pairing::{Pairer, PairingMode, SeqTracker, SyncAccumulator};
use crate::session::SessionRecord;

/// Counters of one pipeline run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
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
        let pairs = self
            .pairer
            .push(raw.stream, raw.sequence, raw.monotonic_ns, frozen);
        out.push(SessionRecord::Frame {
            frame,
            ffc_hint: raw.ffc_hint,
        });
        for p in pairs {
            self.pairs += 1;
            self.sync.add(p.sync_error_ns);
            out.push(SessionRecord::Pair(p));
        }
        Ok(out)
    }

    /// Decides the frames still waiting for a partner (end of recording).
    pub fn finish(&mut self) -> Vec<SessionRecord> {
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
