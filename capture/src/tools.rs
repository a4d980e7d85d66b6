//! `info`, `replay` and `export` over recorded sessions.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::error::CaptureError;
use crate::error::Chain;
use crate::frame::{CapturedFrame, StreamKind};
use crate::session::pairing::{PairingMode, SyncAccumulator, SyncStats};
use crate::session::pipeline::Pipeline;
use crate::session::{
    FrameWindow, PairRecord, SessionItem, SessionRecord, SessionWriter, StatusRecord, read_session,
};

/// Per-stream counts `info` reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StreamInfo {
    pub frames: u64,
    /// Frames missing from sequence gaps.
    pub drops: u64,
    pub ffc_frames: u64,
    /// Buffers rejected as corrupt/short while recording (not in the file).
    pub rejected: u64,
    /// Frames dropped by the recorder's full queue (a subset of `drops`).
    pub queue_drops: u64,
    /// `drops − queue_drops`: sequence gaps the recorder does not account for, i.e. frames
    /// lost at the device (sensor, driver, cable) or while it was disconnected.
    pub source_drops: u64,
    /// Sequence numbers from the first to the last recorded frame, inclusive: equals
    /// `frames + drops` when every missing frame is accounted for.
    pub sequence_span: u64,
    /// Device time from the first to the last recorded frame, seconds.
    pub span_s: f64,
    /// Frame rate from the device's own stamps: `(sequence_span − 1) / span_s`.
    pub rate_hz: f64,
    /// Latest arrival relative to the device stamp, milliseconds, measured from the most
    /// prompt frame (the wall and monotonic clocks' offset cancels): how far delivery fell
    /// behind capture at worst (a device or simulator running late, a reader descheduled).
    pub max_delivery_lag_ms: f64,
}

/// First/last sequence and stamps of one stream, and its delivery lag.
#[derive(Debug, Clone, Copy, Default)]
struct SpanAcc {
    first: Option<(u32, u64)>,
    last: Option<(u32, u64)>,
    /// min and max of `wall − monotonic` (arrival minus stamp, plus a constant clock offset).
    lag_ns: Option<(i128, i128)>,
}

impl SpanAcc {
    fn add(&mut self, sequence: u32, monotonic_ns: u64, wall_unix_ns: u64) {
        self.first.get_or_insert((sequence, monotonic_ns));
        self.last = Some((sequence, monotonic_ns));
        let d = i128::from(wall_unix_ns) - i128::from(monotonic_ns);
        self.lag_ns = Some(
            self.lag_ns
                .map_or((d, d), |(lo, hi)| (lo.min(d), hi.max(d))),
        );
    }

    fn finish(&self, st: &mut StreamInfo) {
        st.source_drops = st.drops.saturating_sub(st.queue_drops);
        if let (Some((s0, t0)), Some((s1, t1))) = (self.first, self.last) {
            st.sequence_span = u64::from(s1.wrapping_sub(s0)) + 1;
            st.span_s = t1.saturating_sub(t0) as f64 * 1e-9;
            if st.span_s > 0.0 {
                st.rate_hz = (st.sequence_span - 1) as f64 / st.span_s;
            }
        }
        if let Some((lo, hi)) = self.lag_ns {
            st.max_delivery_lag_ms = (hi - lo) as f64 * 1e-6;
        }
    }
}

/// What `s3tir-capture info` prints.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SessionSummary {
    pub path: PathBuf,
    pub streams: BTreeMap<String, StreamInfo>,
    pub duration_s: f64,
    pub pairs: u64,
    pub sync: SyncStats,
    pub truncated: bool,
    pub truncation_reason: Option<String>,
    /// Corrupt data that is all in the file (not a cut), with its byte offset: everything before
    /// it was read; `s3tir-capture info` exits non-zero.
    pub damage: Option<crate::session::Damage>,
    pub chunks: u64,
    pub reconnects: u64,
    /// Times a device delivered nothing for the stall timeout and was reopened.
    pub stalls: u64,
    /// FNV-1a over every frame's device buffer and stamps, in file order: equal digests mean
    /// byte-identical frames (`replay` prints the digest of what it pushed through).
    pub frame_digest: String,
    pub thermal_device: String,
    pub attachments: Vec<String>,
    /// Rig-controller trigger pulses recorded.
    pub triggers: u64,
    /// The last controller → camera clock map fitted over matched pulses (`null` when the
    /// rig controller did not trigger): drift, and the sync residual of the pulses.
    pub clock: Option<crate::session::clock_sync::ClockMap>,
}

/// 64-bit FNV-1a.
#[derive(Debug, Clone, Copy)]
pub struct Digest(u64);

impl Default for Digest {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Digest {
    pub fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }

    /// Adds a frame: stream, sequence, monotonic stamp and its device buffer.
    pub fn frame(&mut self, f: &CapturedFrame) {
        let t = f.time();
        self.update(&[u8::from(f.stream() == StreamKind::Rgb)]);
        self.update(&t.sequence.to_le_bytes());
        self.update(&t.monotonic_ns.to_le_bytes());
        match f {
            CapturedFrame::Thermal(th) => {
                self.update(&th.to_y16_bytes());
                self.update(&[th.ffc as u8]);
            }
            CapturedFrame::Rgb(r) => match &r.payload {
                crate::frame::RgbPayload::Mjpeg(b) | crate::frame::RgbPayload::Yuyv(b) => {
                    self.update(b)
                }
            },
        }
    }

    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Summarises a session (reading it to the end, or to its last complete chunk).
pub fn info(path: &Path) -> Result<SessionSummary, CaptureError> {
    let mut s = SessionSummary {
        path: path.to_owned(),
        ..SessionSummary::default()
    };
    let mut th = StreamInfo::default();
    let mut rgb = StreamInfo::default();
    let mut sync = SyncAccumulator::default();
    let mut t_min = u64::MAX;
    let mut t_max = 0u64;
    let mut last_status = StatusRecord::default();
    let mut digest = Digest::default();
    let mut spans = [SpanAcc::default(); 2];
    let out = read_session(path, |item| {
        match item {
            SessionItem::Frame(f) => {
                let frame = crate::session::parse_recorded(path, &f)?;
                digest.frame(&frame);
                t_min = t_min.min(f.raw.monotonic_ns);
                t_max = t_max.max(f.raw.monotonic_ns);
                spans[usize::from(f.raw.stream == StreamKind::Rgb)].add(
                    f.raw.sequence,
                    f.raw.monotonic_ns,
                    f.wall_unix_ns,
                );
                match &frame {
                    CapturedFrame::Thermal(t) => {
                        th.frames += 1;
                        th.ffc_frames += u64::from(t.is_ffc_frozen());
                    }
                    CapturedFrame::Rgb(_) => rgb.frames += 1,
                }
            }
            SessionItem::Pair(p) => {
                s.pairs += 1;
                sync.add(p.sync_error_ns);
            }
            SessionItem::Drop(d) => match d.stream {
                StreamKind::Thermal => th.drops += u64::from(d.missing),
                StreamKind::Rgb => rgb.drops += u64::from(d.missing),
            },
            SessionItem::Status(st) => last_status = st,
            SessionItem::Trigger(_) => s.triggers += 1,
            SessionItem::Clock(c) => {
                if c.matched > 0 {
                    s.clock = Some(c);
                }
            }
        }
        Ok(())
    })?;
    th.rejected = last_status.rejected_thermal;
    rgb.rejected = last_status.rejected_rgb;
    th.queue_drops = last_status.queue_drops_thermal;
    rgb.queue_drops = last_status.queue_drops_rgb;
    s.reconnects = last_status.reconnects;
    s.stalls = last_status.stalls;
    spans[0].finish(&mut th);
    spans[1].finish(&mut rgb);
    s.streams.insert("thermal".into(), th);
    s.streams.insert("rgb".into(), rgb);
    s.duration_s = if t_max > t_min {
        (t_max - t_min) as f64 * 1e-9
    } else {
        0.0
    };
    s.sync = sync.stats();
    s.truncated = out.truncated;
    s.truncation_reason = out.truncation_reason;
    s.damage = out.damage;
    s.chunks = out.chunks;
    s.frame_digest = digest.hex();
    s.thermal_device = out.info.thermal_device;
    s.attachments = out.attachments.keys().cloned().collect();
    Ok(s)
}

/// What a replay did.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ReplayReport {
    pub frames: u64,
    pub rejected: u64,
    pub pairs: u64,
    pub drops: u64,
    pub truncated: bool,
    pub frame_digest: String,
    /// Pairs the replayed pipeline produced that differ from the recorded ones.
    pub pair_mismatches: u64,
}

/// Pushes every recorded device buffer through the live pipeline (parse, drop detection,
/// pairing) and, with `out`, writes what it produces as a new session. `realtime` paces the
/// buffers by their recorded monotonic stamps. `visit` sees each produced record.
pub fn replay(
    path: &Path,
    out: Option<&Path>,
    realtime: bool,
    pairing: Option<PairingMode>,
    mut visit: impl FnMut(&SessionRecord),
) -> Result<ReplayReport, CaptureError> {
    let read_info = read_session(path, |_| Ok(()))?;
    let mut writer = match out {
        Some(o) => Some(SessionWriter::create(o, &read_info.info)?),
        None => None,
    };
    // The recording's own pairing unless overridden: same inputs, same pipeline, same output.
    let pairing = pairing
        .or_else(|| serde_json::from_str(&read_info.info.pairing).ok())
        .unwrap_or(PairingMode::Nearest {
            tolerance_ns: crate::session::pairing::DEFAULT_TOLERANCE_NS,
        });
    let mut pipe = Pipeline::new(pairing);
    let mut report = ReplayReport::default();
    let mut digest = Digest::default();
    let mut recorded_pairs: Vec<PairRecord> = Vec::new();
    let mut produced_pairs: Vec<PairRecord> = Vec::new();
    let mut pace: Option<(Instant, u64)> = None;
    let device = path.display().to_string();
    let mut handle = |recs: Vec<SessionRecord>,
                      digest: &mut Digest,
                      produced_pairs: &mut Vec<PairRecord>,
                      writer: &mut Option<SessionWriter>|
     -> Result<(), CaptureError> {
        for r in &recs {
            match r {
                SessionRecord::Frame { frame, .. } => digest.frame(frame),
                SessionRecord::Pair(p) => produced_pairs.push(*p),
                _ => {}
            }
            visit(r);
            if let Some(w) = writer.as_mut() {
                w.write(r)?;
            }
        }
        Ok(())
    };
    let outcome = read_session(path, |item| {
        match item {
            SessionItem::Frame(f) => {
                if realtime {
                    let (t0, m0) = *pace.get_or_insert((Instant::now(), f.raw.monotonic_ns));
                    let due = Duration::from_nanos(f.raw.monotonic_ns.saturating_sub(m0));
                    if let Some(wait) = due.checked_sub(t0.elapsed()) {
                        std::thread::sleep(wait);
                    }
                }
                match pipe.push(&device, &f.raw, f.wall_unix_ns) {
                    Ok(recs) => {
                        report.frames += 1;
                        handle(recs, &mut digest, &mut produced_pairs, &mut writer)?;
                    }
                    Err(e) => {
                        report.rejected += 1;
                        tracing::warn!("recorded frame rejected on replay: {}", Chain(&e));
                    }
                }
            }
            SessionItem::Pair(p) => recorded_pairs.push(p),
            SessionItem::Status(s) => {
                if let Some(w) = writer.as_mut() {
                    w.write(&SessionRecord::Status(s))?;
                }
            }
            SessionItem::Drop(_) => {}
            // Inputs of the pipeline, in their recorded order: the rough clock map and the
            // pulses. Fitted maps are outputs: re-derived, not read.
            SessionItem::Trigger(t) => {
                let recs = pipe.push_trigger(t);
                handle(recs, &mut digest, &mut produced_pairs, &mut writer)?;
            }
            SessionItem::Clock(c) => {
                if c.matched == 0 {
                    let recs = pipe.set_rough_clock(c);
                    handle(recs, &mut digest, &mut produced_pairs, &mut writer)?;
                }
            }
        }
        Ok(())
    })?;
    let tail = pipe.finish();
    handle(tail, &mut digest, &mut produced_pairs, &mut writer)?;
    if let Some(w) = writer {
        w.finish()?;
    }
    // A truncated recording lost its last pairs (and a replay decides pending ones at the
    // end): compare only the recorded prefix.
    report.pair_mismatches = recorded_pairs
        .iter()
        .zip(&produced_pairs)
        .filter(|(a, b)| a != b)
        .count() as u64
        + recorded_pairs.len().saturating_sub(produced_pairs.len()) as u64;
    report.pairs = pipe.pairs;
    report.drops = pipe.thermal.drops + pipe.rgb.drops;
    report.truncated = outcome.truncated;
    report.frame_digest = digest.hex();
    Ok(report)
}

/// Writes the paired frames in the `s3tir-calib` board-folder layout: `thermal/NNNN.png`
/// (16-bit grey, words untouched) and `rgb/NNNN.png` (8-bit RGB), pair `k` under the same name.
/// Returns the number of pairs written.
pub fn export(path: &Path, dir: &Path) -> Result<u64, CaptureError> {
    export_with_progress(path, dir, |_| {})
}

/// [`export`], calling `on_pair` with the number of pairs written so far after each pair (the
/// CLI's progress line).
pub fn export_with_progress(
    path: &Path,
    dir: &Path,
    mut on_pair: impl FnMut(u64),
) -> Result<u64, CaptureError> {
    let mk = |d: PathBuf| {
        std::fs::create_dir_all(&d).map_err(|e| CaptureError::ExportWrite {
            path: d.clone(),
            what: "create folder",
            source: e.into(),
        })
    };
    mk(dir.join("thermal"))?;
    mk(dir.join("rgb"))?;
    // Keyed by arrival: sequences restart when a device is reopened.
    let mut thermal = FrameWindow::<CapturedFrame>::default();
    let mut rgb = FrameWindow::<CapturedFrame>::default();
    let mut k = 0u64;
    read_session(path, |item| {
        match item {
            SessionItem::Frame(f) => {
                let frame = crate::session::parse_recorded(path, &f)?;
                let map = match frame.stream() {
                    StreamKind::Thermal => &mut thermal,
                    StreamKind::Rgb => &mut rgb,
                };
                map.push(f.raw.sequence, frame);
            }
            SessionItem::Pair(p) => {
                let (Some(CapturedFrame::Thermal(t)), Some(CapturedFrame::Rgb(r))) =
                    (thermal.get(p.thermal_sequence), rgb.get(p.rgb_sequence))
                else {
                    return Ok(());
                };
                let tp = dir.join(format!("thermal/{k:04}.png"));
                let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
                    t.width,
                    t.height,
                    t.pixels.clone(),
                )
                .ok_or_else(|| CaptureError::Export {
                    path: tp.clone(),
                    reason: "pixel count does not match size".into(),
                })?;
                img.save(&tp).map_err(|e| CaptureError::ExportWrite {
                    path: tp.clone(),
                    what: "write PNG",
                    source: e.into(),
                })?;
                let rp = dir.join(format!("rgb/{k:04}.png"));
                let px = r.to_rgb8(&path.display().to_string())?;
                let img = image::RgbImage::from_raw(r.width, r.height, px).ok_or_else(|| {
                    CaptureError::Export {
                        path: rp.clone(),
                        reason: "decoded size does not match the recorded size".into(),
                    }
                })?;
                img.save(&rp).map_err(|e| CaptureError::ExportWrite {
                    path: rp.clone(),
                    what: "write PNG",
                    source: e.into(),
                })?;
                k += 1;
                on_pair(k);
            }
            _ => {}
        }
        Ok(())
    })?;
    Ok(k)
}
