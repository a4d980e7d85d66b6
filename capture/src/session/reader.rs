//! The crash-tolerant reader: [`read_session`] streams a session from its start, up to the
//! last complete chunk of a cut file, and reports damage with its offset.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Read;
use std::path::Path;

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use serde::{Deserialize, Serialize};

use crate::device::FourCc;
use crate::error::CaptureError;
use crate::error::Chain;
use crate::frame::{CapturedFrame, FfcState, RawFrame, StreamKind, ThermalUnits};
use crate::session::chunk::{MAX_RECORD_BYTES, RECORD_PREFIX_LEN, decode_chunk, split_chunk};
use crate::session::clock_sync::ClockMap;
use crate::session::pairing::{DropRecord, PairRecord};
use crate::session::records::{
    RgbMeta, SessionInfo, StatusRecord, ThermalMeta, TriggerRecord, topic,
};
use crate::session::ros1::{decode_ros_compressed, decode_ros_image};

/// A frame as recorded: the device buffer rebuilt exactly, plus the recorded wall clock.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedFrame {
    pub raw: RawFrame,
    pub wall_unix_ns: u64,
}

/// One item of a session, in file order.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionItem {
    Frame(RecordedFrame),
    Pair(PairRecord),
    Drop(DropRecord),
    Status(StatusRecord),
    Trigger(TriggerRecord),
    Clock(ClockMap),
}

/// What a read found besides the items.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadOutcome {
    pub info: SessionInfo,
    /// Attachments by name.
    pub attachments: BTreeMap<String, Vec<u8>>,
    /// The file ends before its footer (crash, kill -9, full disk) or holds a corrupt record:
    /// everything up to the last complete chunk was read.
    pub truncated: bool,
    /// Why reading stopped early, when `truncated`.
    pub truncation_reason: Option<String>,
    /// Set when reading stopped at corrupt data that is all in the file (not a cut): a bad
    /// CRC, an impossible length. The items before it were read (`truncated` is set too).
    pub damage: Option<Damage>,
    /// Complete chunks read.
    pub chunks: u64,
}

/// Where and why a session file is damaged.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Damage {
    /// Byte offset of the record that could not be read.
    pub offset: u64,
    pub reason: String,
}

/// Reads a session from the start, calling `visit` for every item in file order. Never needs
/// the summary: a file cut anywhere reads up to its last complete chunk, with
/// `truncated = true` in the outcome; corrupt data that is all in the file stops the read the
/// same way and is described in [`ReadOutcome::damage`]. No length read from the file is
/// allocated before it is checked (module docs). `visit` errors stop the read and are returned.
pub fn read_session(
    path: &Path,
    mut visit: impl FnMut(SessionItem) -> Result<(), CaptureError>,
) -> Result<ReadOutcome, CaptureError> {
    let mut file = File::open(path).map_err(io_error(path, "open"))?;
    let file_len = file.metadata().map_err(io_error(path, "stat"))?.len();
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_emit_chunks(true)
            // A chunk in progress when the recorder died still carries the writer's
            // placeholder length (it is patched when the chunk ends): the limit turns it into
            // a clean "record too large" stop instead of an overflow.
            .with_record_length_limit(MAX_RECORD_BYTES),
    );
    let mut scan = SessionScan {
        path,
        out: ReadOutcome::default(),
        topics: BTreeMap::new(),
        pending_thermal: None,
        pending_rgb: None,
        saw_footer: false,
    };
    let stop = scan.read_records(&mut file, &mut reader, &mut visit)?;
    scan.conclude(stop, &file, file_len)
        .map_err(io_error(path, "read"))
}

/// The error of a failed file operation `what` on the session at `path`.
fn io_error(path: &Path, what: &'static str) -> impl FnOnce(std::io::Error) -> CaptureError {
    let path = path.to_owned();
    move |source| CaptureError::SessionIo { path, what, source }
}

/// A read in progress: what it found so far, and what messages need across records (the
/// channels' topics, an image's meta message that comes before it).
struct SessionScan<'p> {
    path: &'p Path,
    out: ReadOutcome,
    topics: BTreeMap<u16, String>,
    pending_thermal: Option<ThermalMeta>,
    pending_rgb: Option<RgbMeta>,
    saw_footer: bool,
}

impl SessionScan<'_> {
    /// Reads the file-level records in order, returning where reading stopped early (the
    /// offset of the record that could not be read, and why), if it did.
    fn read_records(
        &mut self,
        file: &mut File,
        reader: &mut LinearReader,
        visit: &mut impl FnMut(SessionItem) -> Result<(), CaptureError>,
    ) -> Result<Option<(u64, String)>, CaptureError> {
        // Offset of the next file-level record (after the 8-byte magic).
        let mut offset: u64 = MAGIC_LEN;
        while let Some(event) = reader.next_event() {
            let event = match event {
                Ok(e) => e,
                Err(e) => return Ok(Some((offset, Chain(&e).to_string()))),
            };
            match event {
                LinearReadEvent::ReadRequest(n) => {
                    let got = read_retrying(file, reader.insert(n))
                        .map_err(io_error(self.path, "read"))?;
                    reader.notify_read(got);
                }
                LinearReadEvent::Record { data, opcode } => {
                    let record_offset = offset;
                    offset += RECORD_PREFIX_LEN + data.len() as u64;
                    if let Some(reason) = self.file_record(opcode, data, visit)? {
                        return Ok(Some((record_offset, reason)));
                    }
                }
            }
        }
        Ok(None)
    }

    /// Handles one file-level record; returns why reading must stop at it (a corrupt record
    /// or chunk), if it must.
    fn file_record(
        &mut self,
        opcode: u8,
        data: &[u8],
        visit: &mut impl FnMut(SessionItem) -> Result<(), CaptureError>,
    ) -> Result<Option<String>, CaptureError> {
        let record = match mcap::parse_record(opcode, data) {
            Ok(r) => r,
            Err(e) => {
                return Ok(Some(format!(
                    "corrupt record (opcode {opcode:#04x}): {}",
                    Chain(&e)
                )));
            }
        };
        let Record::Chunk { header, data } = record else {
            self.record(record, visit)?;
            return Ok(None);
        };
        // Decompress the whole chunk before handing out anything from it, so a damaged chunk
        // contributes nothing.
        let recs = match decode_chunk(&header, &data).and_then(|body| split_chunk(&body)) {
            Ok(recs) => recs,
            Err(reason) => return Ok(Some(format!("corrupt chunk: {}", Chain(&reason)))),
        };
        self.out.chunks += 1;
        for r in recs {
            self.record(r, visit)?;
        }
        Ok(None)
    }

    /// Handles one record (file-level or from a chunk): channels, messages (decoded and
    /// visited), session metadata, attachments, the footer.
    fn record(
        &mut self,
        rec: Record<'_>,
        visit: &mut impl FnMut(SessionItem) -> Result<(), CaptureError>,
    ) -> Result<(), CaptureError> {
        match rec {
            Record::Channel(c) => {
                self.topics.insert(c.id, c.topic);
            }
            Record::Message { header, data } => {
                let t = self
                    .topics
                    .get(&header.channel_id)
                    .cloned()
                    .unwrap_or_default();
                if let Some(item) = decode_message(
                    self.path,
                    &t,
                    header.sequence,
                    &data,
                    &mut self.pending_thermal,
                    &mut self.pending_rgb,
                )? {
                    visit(item)?;
                }
            }
            Record::Metadata(m) if m.name == "s3tir.session" => {
                self.out.info = SessionInfo::from_map(&m.metadata);
            }
            Record::Attachment { header, data, .. } => {
                self.out.attachments.insert(header.name, data.into_owned());
            }
            Record::Footer(_) => self.saw_footer = true,
            _ => {}
        }
        Ok(())
    }

    /// The outcome: truncated (a cut, or damage when the bad record is all in the file) when
    /// reading stopped early at `stop`, or when the file ends without its footer.
    fn conclude(
        mut self,
        stop: Option<(u64, String)>,
        file: &File,
        file_len: u64,
    ) -> std::io::Result<ReadOutcome> {
        if let Some((at, reason)) = stop {
            self.out.truncated = true;
            if is_cut(file, file_len, at)? {
                self.out.truncation_reason = Some(reason);
            } else {
                self.out.truncation_reason = Some(format!("damaged at byte {at}: {reason}"));
                self.out.damage = Some(Damage { offset: at, reason });
            }
        } else if !self.saw_footer {
            self.out.truncated = true;
            self.out.truncation_reason = Some("file ends without a footer".into());
        }
        Ok(self.out)
    }
}

/// Reads what `file` has into `buf`, retrying when interrupted.
fn read_retrying(file: &mut File, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match file.read(buf) {
            Ok(k) => return Ok(k),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
}

/// MCAP's magic (`\x89MCAP0\r\n`) before the first record.
const MAGIC_LEN: u64 = 8;

/// Whether the file simply stops at or inside the record at `offset` (a cut: crash, kill,
/// full disk, or the zero-filled tail a power cut can leave) rather than holding corrupt data.
fn is_cut(file: &File, file_len: u64, offset: u64) -> std::io::Result<bool> {
    use std::os::unix::fs::FileExt;
    let mut prefix = [0u8; RECORD_PREFIX_LEN as usize];
    if offset.saturating_add(RECORD_PREFIX_LEN) > file_len {
        return Ok(true);
    }
    file.read_exact_at(&mut prefix, offset)?;
    let mut len = [0u8; 8];
    len.copy_from_slice(&prefix[1..]);
    let claimed_end = offset
        .saturating_add(RECORD_PREFIX_LEN)
        .saturating_add(u64::from_le_bytes(len));
    if claimed_end > file_len {
        return Ok(true);
    }
    // Only zeros from here to the end: blocks allocated but never written.
    let mut buf = vec![0u8; 1 << 16];
    let mut at = offset;
    while at < file_len {
        let n = file.read_at(&mut buf, at)?;
        if n == 0 {
            break;
        }
        if buf[..n].iter().any(|&b| b != 0) {
            return Ok(false);
        }
        at += n as u64;
    }
    Ok(true)
}

fn decode_message(
    path: &Path,
    topic_name: &str,
    sequence: u32,
    data: &[u8],
    pending_thermal: &mut Option<ThermalMeta>,
    pending_rgb: &mut Option<RgbMeta>,
) -> Result<Option<SessionItem>, CaptureError> {
    let bad = |reason: String| CaptureError::SessionMessage {
        path: path.to_owned(),
        topic: topic_name.to_owned(),
        sequence,
        reason,
    };
    let json_err = |source: serde_json::Error| CaptureError::SessionJson {
        path: path.to_owned(),
        topic: topic_name.to_owned(),
        sequence,
        source,
    };
    fn json<T: for<'a> Deserialize<'a>>(data: &[u8]) -> Result<T, serde_json::Error> {
        serde_json::from_slice(data)
    }
    Ok(match topic_name {
        topic::THERMAL_META => {
            *pending_thermal = Some(json(data).map_err(json_err)?);
            None
        }
        topic::RGB_META => {
            *pending_rgb = Some(json(data).map_err(json_err)?);
            None
        }
        topic::THERMAL_IMAGE => {
            let meta = pending_thermal
                .take()
                .filter(|m| m.sequence == sequence)
                .ok_or_else(|| bad("image without its /thermal/meta message".into()))?;
            let img =
                decode_ros_image(data).ok_or_else(|| bad("not a sensor_msgs/Image".into()))?;
            let mut payload = img.data.to_vec();
            for w in &meta.telemetry_words {
                payload.extend_from_slice(&w.to_le_bytes());
            }
            let (Some(height), Some(bytes_per_line)) = (
                img.height.checked_add(meta.telemetry_rows),
                img.width.checked_mul(2),
            ) else {
                return Err(bad(format!(
                    "impossible size {}x{} + {} telemetry rows",
                    img.width, img.height, meta.telemetry_rows
                )));
            };
            Some(SessionItem::Frame(RecordedFrame {
                raw: RawFrame {
                    stream: StreamKind::Thermal,
                    fourcc: FourCc::Y16,
                    width: img.width,
                    height,
                    bytes_per_line,
                    telemetry_rows: meta.telemetry_rows,
                    units: meta.units,
                    ffc_hint: meta.ffc_hint,
                    sequence: meta.sequence,
                    monotonic_ns: meta.monotonic_ns,
                    payload,
                },
                wall_unix_ns: meta.wall_unix_ns,
            }))
        }
        topic::RGB_COMPRESSED | topic::RGB_IMAGE => {
            let meta = pending_rgb
                .take()
                .filter(|m| m.sequence == sequence)
                .ok_or_else(|| bad("image without its /rgb/meta message".into()))?;
            let (payload, bpl) = if topic_name == topic::RGB_COMPRESSED {
                let (_, _, d) = decode_ros_compressed(data)
                    .ok_or_else(|| bad("not a sensor_msgs/CompressedImage".into()))?;
                (d.to_vec(), 0)
            } else {
                let img =
                    decode_ros_image(data).ok_or_else(|| bad("not a sensor_msgs/Image".into()))?;
                (img.data.to_vec(), img.step)
            };
            Some(SessionItem::Frame(RecordedFrame {
                raw: RawFrame {
                    stream: StreamKind::Rgb,
                    fourcc: meta.fourcc,
                    width: meta.width,
                    height: meta.height,
                    bytes_per_line: bpl,
                    telemetry_rows: 0,
                    units: ThermalUnits::RawCounts,
                    ffc_hint: FfcState::Unknown,
                    sequence: meta.sequence,
                    monotonic_ns: meta.monotonic_ns,
                    payload,
                },
                wall_unix_ns: meta.wall_unix_ns,
            }))
        }
        topic::PAIRS => Some(SessionItem::Pair(json(data).map_err(json_err)?)),
        topic::DROPS => Some(SessionItem::Drop(json(data).map_err(json_err)?)),
        topic::STATUS => Some(SessionItem::Status(json(data).map_err(json_err)?)),
        topic::TRIGGERS => Some(SessionItem::Trigger(json(data).map_err(json_err)?)),
        topic::CLOCK => Some(SessionItem::Clock(json(data).map_err(json_err)?)),
        _ => None,
    })
}

/// Convenience for tests and tools: the frame a recorded item parses to.
pub fn parse_recorded(path: &Path, f: &RecordedFrame) -> Result<CapturedFrame, CaptureError> {
    CapturedFrame::from_raw(&path.display().to_string(), &f.raw, f.wall_unix_ns)
}
