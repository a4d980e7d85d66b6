//! Sessions in MCAP: writer and crash-tolerant reader.
//!
//! # Layout
//!
//! | topic | schema (encoding) | one message per |
//! |---|---|---|
//! | `/thermal/image` | `sensor_msgs/Image` (`ros1msg`/`ros1`), encoding `mono16`, little-endian | thermal frame (image rows only) |
//! | `/thermal/meta` | `s3tir.ThermalMeta` (JSON) | thermal frame: sequence, clocks, FFC, units, telemetry rows (raw + decoded) |
//! | `/rgb/compressed` | `sensor_msgs/CompressedImage` (`ros1`), format `jpeg` | MJPEG frame, bytes untouched |
//! | `/rgb/image` | `sensor_msgs/Image` (`ros1`), encoding `yuv422_yuy2` | YUYV frame, bytes untouched |
//! | `/rgb/meta` | `s3tir.RgbMeta` (JSON) | RGB frame |
//! | `/pairs` | `s3tir.Pair` (JSON) | thermal↔RGB pair |
//! | `/drops` | `s3tir.Drop` (JSON) | sequence gap |
//! | `/capture/status` | `s3tir.Status` (JSON) | second of recording (rejected buffers, queue drops, reconnects) |
//! | `/rig/triggers` | `s3tir.Trigger` (JSON) | rig-controller trigger pulse: count, controller-clock time |
//! | `/rig/clock` | `s3tir.ClockMap` (JSON) | controller → camera clock map: the rough one from a status exchange (`matched` 0, first), then each refit over matched pulses |
//!
//! Images use the ROS 1 message encoding because Foxglove/Lichtblick display `sensor_msgs/Image`
//! `mono16` and `sensor_msgs/CompressedImage` natively, the schema is plain text (no protobuf
//! descriptor to generate), and the encoding is a 30-byte header before the untouched pixel
//! bytes (JSON would have to base64 655 kB per Boson frame). A frame's meta message is written
//! just before its image message, in the same chunk, with the same MCAP `sequence` (the V4L2
//! sequence). MCAP `log_time` is the wall clock, `publish_time` is `CLOCK_MONOTONIC`.
//!
//! Metadata records: `s3tir.session` (tool version, devices, units, pairing). Attachments:
//! `calibration` when a calibration file is given.
//!
//! # Compression and crash safety
//!
//! Chunks are LZ4-compressed: LZ4 compresses at several hundred MB/s per core, and most of the
//! bytes are thermal noise and already-compressed JPEG where zstd's better ratio buys little
//! while its CPU cost would compete with capture on a Raspberry Pi-class rig.
//!
//! The writer ends the current chunk (mcap's `Writer::flush`, which finishes the chunk and
//! flushes the file) at least every [`FLUSH_INTERVAL`], and only between frames, so a
//! `kill -9` loses at most the chunk in progress (≤ 0.5 s: the page cache holds the rest).
//! A power cut also loses what is in the page cache: at a chunk end the writer calls
//! `fdatasync` when [`SYNC_INTERVAL`] has passed since the last one (and the file's directory
//! is synced once at creation, so the file itself survives), so a power cut loses at most the
//! last ~1.5 s (one sync interval plus the chunk in progress) provided the storage honours
//! flushes (ext4's default barriers do; a card or USB bridge that acknowledges writes it has
//! only cached can lose more: no software bound holds there). The cost is measured by
//! `s3tir-capture bench` (`sync_ms_mean`, `sync_ms_max` and the no-sync reference run). The reader does not rely on the summary or
//! footer: it streams records from the start, decompresses whole chunks only, and stops at
//! the first incomplete or corrupt record, reporting the session as `truncated`.
//!
//! # Hostile and damaged files
//!
//! Every length in a file is checked against what is really there before anything is
//! allocated: file-level records against [`MAX_RECORD_BYTES`], a chunk's claimed uncompressed
//! size against [`MAX_RECORD_BYTES`] and against what LZ4 can expand its compressed bytes to
//! ([`LZ4_MAX_RATIO`]), and each record inside a chunk against the bytes left in the chunk.
//! Chunks are decompressed and split here ([`decode_chunk`]), not by `mcap::read::ChunkReader`,
//! which reserves an inner record's claimed length before any check (a 9-byte inner header
//! could ask for exabytes). A file that stops early is a *cut* (crash, kill, full disk: the
//! normal case, [`ReadOutcome::truncated`]); corrupt data that is all there (a bad CRC, an
//! impossible length) is *damage* ([`ReadOutcome::damage`], with its byte offset), which
//! `s3tir-capture info` reports as an error.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Read};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use serde::{Deserialize, Serialize};

use crate::device::FourCc;
use crate::error::CaptureError;
use crate::frame::{CapturedFrame, FfcState, RawFrame, RgbPayload, StreamKind, ThermalUnits};
use crate::telemetry::LeptonTelemetry;

/// Longest time between chunk ends (the most a crash loses).
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(500);
/// Longest time between `fdatasync`s of the session file (at a chunk end): with
/// [`FLUSH_INTERVAL`], the most a power cut loses is the last ~1.5 s.
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);
/// Largest record the reader accepts (a chunk holds at most ~[`MAX_CHUNK_BYTES`] plus one
/// frame; a 4K YUYV frame is 16.6 MB).
pub const MAX_RECORD_BYTES: usize = 256 * 1024 * 1024;
/// A chunk is also ended when it holds this many uncompressed bytes.
pub const MAX_CHUNK_BYTES: usize = 8 * 1024 * 1024;
/// LZ4 cannot expand data by more than about 255× (a match encodes at most 255 bytes per
/// length byte); a chunk claiming more than this times its compressed size is damaged.
pub const LZ4_MAX_RATIO: u64 = 256;

pub mod topic {
    pub const THERMAL_IMAGE: &str = "/thermal/image";
    pub const THERMAL_META: &str = "/thermal/meta";
    pub const RGB_COMPRESSED: &str = "/rgb/compressed";
    pub const RGB_IMAGE: &str = "/rgb/image";
    pub const RGB_META: &str = "/rgb/meta";
    pub const PAIRS: &str = "/pairs";
    pub const DROPS: &str = "/drops";
    pub const STATUS: &str = "/capture/status";
    pub const TRIGGERS: &str = "/rig/triggers";
    pub const CLOCK: &str = "/rig/clock";
}

const HEADER_DEF: &str = "================================================================================\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n";

fn image_schema() -> String {
    format!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n{HEADER_DEF}"
    )
}

fn compressed_schema() -> String {
    format!("std_msgs/Header header\nstring format\nuint8[] data\n{HEADER_DEF}")
}

/// Per-frame metadata of a thermal frame (`/thermal/meta`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalMeta {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub wall_unix_ns: u64,
    pub width: u32,
    pub height: u32,
    pub units: ThermalUnits,
    /// State after telemetry decoding (what pairing used).
    pub ffc: FfcState,
    /// State the device reported out of band (kept so replay re-derives `ffc` identically).
    pub ffc_hint: FfcState,
    pub telemetry_rows: u32,
    pub telemetry_words: Vec<u16>,
    pub telemetry: Option<LeptonTelemetry>,
}

/// Per-frame metadata of an RGB frame (`/rgb/meta`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RgbMeta {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub wall_unix_ns: u64,
    pub fourcc: FourCc,
    pub width: u32,
    pub height: u32,
}

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

/// Counters the recorder writes every second (`/capture/status`); the last one holds totals.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StatusRecord {
    pub wall_unix_ns: u64,
    /// Buffers that failed to parse (short, corrupt): counted, not recorded.
    pub rejected_thermal: u64,
    pub rejected_rgb: u64,
    /// Frames dropped because the recorder's bounded queue was full (slow disk).
    pub queue_drops_thermal: u64,
    pub queue_drops_rgb: u64,
    pub reconnects: u64,
    pub serial_errors: u64,
    /// Times a device delivered nothing for the stall timeout and was reopened (absent in
    /// sessions recorded before the watchdog).
    #[serde(default)]
    pub stalls: u64,
}

/// A rig-controller trigger pulse (`/rig/triggers`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct TriggerRecord {
    pub count: u32,
    /// The controller's clock at the pulse edge, nanoseconds.
    pub controller_ns: u64,
}

/// What the pipeline hands to the writer.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionRecord {
    Frame {
        frame: CapturedFrame,
        ffc_hint: FfcState,
    },
    Pair(PairRecord),
    Drop(DropRecord),
    Status(StatusRecord),
    Trigger(TriggerRecord),
    Clock(crate::clock_sync::ClockMap),
}

/// Session-level description written as the `s3tir.session` metadata record.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SessionInfo {
    pub tool: String,
    pub thermal_device: String,
    pub rgb_device: Option<String>,
    pub thermal_serial: Option<String>,
    pub pairing: String,
    pub notes: String,
}

impl SessionInfo {
    fn to_map(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("tool".into(), self.tool.clone());
        m.insert("thermal_device".into(), self.thermal_device.clone());
        if let Some(r) = &self.rgb_device {
            m.insert("rgb_device".into(), r.clone());
        }
        if let Some(s) = &self.thermal_serial {
            m.insert("thermal_serial".into(), s.clone());
        }
        m.insert("pairing".into(), self.pairing.clone());
        m.insert("notes".into(), self.notes.clone());
        m
    }

    fn from_map(m: &BTreeMap<String, String>) -> Self {
        let get = |k: &str| m.get(k).cloned().unwrap_or_default();
        Self {
            tool: get("tool"),
            thermal_device: get("thermal_device"),
            rgb_device: m.get("rgb_device").cloned(),
            thermal_serial: m.get("thermal_serial").cloned(),
            pairing: get("pairing"),
            notes: get("notes"),
        }
    }
}

// ---------------------------------------------------------------- ROS 1 encoding

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    put_u32(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}

fn put_header(out: &mut Vec<u8>, seq: u32, wall_unix_ns: u64, frame_id: &str) {
    put_u32(out, seq);
    put_u32(out, (wall_unix_ns / 1_000_000_000) as u32);
    put_u32(out, (wall_unix_ns % 1_000_000_000) as u32);
    put_str(out, frame_id);
}

/// `sensor_msgs/Image` in ROS 1 serialization (`img.seq` is the header's `seq`).
pub fn encode_ros_image(img: &RosImage<'_>, wall_unix_ns: u64, frame_id: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + img.data.len());
    put_header(&mut out, img.seq, wall_unix_ns, frame_id);
    put_u32(&mut out, img.height);
    put_u32(&mut out, img.width);
    put_str(&mut out, img.encoding);
    out.push(0); // is_bigendian
    put_u32(&mut out, img.step);
    put_u32(&mut out, img.data.len() as u32);
    out.extend_from_slice(img.data);
    out
}

/// `sensor_msgs/CompressedImage` in ROS 1 serialization.
pub fn encode_ros_compressed(seq: u32, wall_unix_ns: u64, frame_id: &str, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(48 + data.len());
    put_header(&mut out, seq, wall_unix_ns, frame_id);
    put_str(&mut out, "jpeg");
    put_u32(&mut out, data.len() as u32);
    out.extend_from_slice(data);
    out
}

struct Cursor<'a> {
    buf: &'a [u8],
}

impl<'a> Cursor<'a> {
    fn u32(&mut self) -> Option<u32> {
        let (h, t) = self.buf.split_first_chunk::<4>()?;
        self.buf = t;
        Some(u32::from_le_bytes(*h))
    }
    fn bytes(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.buf.len() < n {
            return None;
        }
        let (h, t) = self.buf.split_at(n);
        self.buf = t;
        Some(h)
    }
    fn sized(&mut self) -> Option<&'a [u8]> {
        let n = self.u32()? as usize;
        self.bytes(n)
    }
}

/// Decoded `sensor_msgs/Image` fields this crate needs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RosImage<'a> {
    pub seq: u32,
    pub width: u32,
    pub height: u32,
    pub encoding: &'a str,
    pub step: u32,
    pub data: &'a [u8],
}

pub fn decode_ros_image(buf: &[u8]) -> Option<RosImage<'_>> {
    let mut c = Cursor { buf };
    let seq = c.u32()?;
    c.bytes(8)?;
    c.sized()?;
    let height = c.u32()?;
    let width = c.u32()?;
    let encoding = std::str::from_utf8(c.sized()?).ok()?;
    c.bytes(1)?;
    let step = c.u32()?;
    let data = c.sized()?;
    Some(RosImage {
        seq,
        width,
        height,
        encoding,
        step,
        data,
    })
}

/// Returns (seq, format, data) of a `sensor_msgs/CompressedImage`.
pub fn decode_ros_compressed(buf: &[u8]) -> Option<(u32, &str, &[u8])> {
    let mut c = Cursor { buf };
    let seq = c.u32()?;
    c.bytes(8)?;
    c.sized()?;
    let format = std::str::from_utf8(c.sized()?).ok()?;
    let data = c.sized()?;
    Some((seq, format, data))
}

// ---------------------------------------------------------------- writer

#[derive(Debug, Default, Clone, Copy)]
struct Channels {
    thermal_image: u16,
    thermal_meta: u16,
    rgb_compressed: u16,
    rgb_image: u16,
    rgb_meta: u16,
    pairs: u16,
    drops: u16,
    status: u16,
    triggers: u16,
    clock: u16,
}

/// Writes a session. Call [`SessionWriter::tick`] regularly (the daemon does after every
/// record and on a timer) so chunks end at least every [`FLUSH_INTERVAL`].
pub struct SessionWriter {
    path: PathBuf,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    /// A second handle on the same open file, for `fdatasync` (the first is inside mcap's
    /// writer).
    sync_handle: File,
    ch: Channels,
    last_flush: Instant,
    last_sync: Instant,
    bytes_in_chunk: usize,
    bytes_written: u64,
    flush_interval: Duration,
    /// `None` only for the bench's reference run (never for a recording).
    sync_interval: Option<Duration>,
    syncs: SyncStats,
}

/// How often and how long the writer waited for the disk (`fdatasync`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct SyncStats {
    pub count: u64,
    pub total: Duration,
    pub max: Duration,
}

impl std::fmt::Debug for SessionWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionWriter")
            .field("path", &self.path)
            .field("bytes_written", &self.bytes_written)
            .finish_non_exhaustive()
    }
}

impl SessionWriter {
    /// Creates `path` and writes the header, schemas, channels and metadata. An existing file
    /// is never overwritten ([`CaptureError::SessionExists`]): it may be a recording.
    pub fn create(path: &Path, info: &SessionInfo) -> Result<Self, CaptureError> {
        let io = |what: &'static str| {
            move |source| CaptureError::SessionIo {
                path: path.to_owned(),
                what,
                source,
            }
        };
        let file = match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
        {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                return Err(CaptureError::SessionExists {
                    path: path.to_owned(),
                });
            }
            Err(e) => return Err(io("create")(e)),
        };
        let sync_handle = file.try_clone().map_err(io("dup"))?;
        // The new directory entry is made durable once, so a power cut cannot lose the file.
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        match File::open(dir).and_then(|d| d.sync_all()) {
            Ok(()) => {}
            // Some filesystems (FUSE, network mounts) cannot sync a directory: the recording
            // goes on, with the file's own syncs only.
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::InvalidInput | std::io::ErrorKind::Unsupported
                ) =>
            {
                tracing::warn!(dir = %dir.display(), "cannot sync the session's folder: {e}");
            }
            Err(e) => return Err(io("sync directory")(e)),
        }
        let mcap_err = |what: &'static str| {
            let path = path.to_owned();
            move |source| CaptureError::Mcap { path, what, source }
        };
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .chunk_size(None) // chunks end on our schedule, between frames
            .profile("ros1")
            .library(format!("s3tir-capture {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(mcap_err("write header"))?;
        let img = w
            .add_schema("sensor_msgs/Image", "ros1msg", image_schema().as_bytes())
            .map_err(mcap_err("add schema"))?;
        let cmp = w
            .add_schema(
                "sensor_msgs/CompressedImage",
                "ros1msg",
                compressed_schema().as_bytes(),
            )
            .map_err(mcap_err("add schema"))?;
        let json_schema = |w: &mut mcap::Writer<_>, name: &str| {
            w.add_schema(name, "jsonschema", br#"{"type":"object"}"#)
        };
        let tm = json_schema(&mut w, "s3tir.ThermalMeta").map_err(mcap_err("add schema"))?;
        let rm = json_schema(&mut w, "s3tir.RgbMeta").map_err(mcap_err("add schema"))?;
        let pr = json_schema(&mut w, "s3tir.Pair").map_err(mcap_err("add schema"))?;
        let dr = json_schema(&mut w, "s3tir.Drop").map_err(mcap_err("add schema"))?;
        let st = json_schema(&mut w, "s3tir.Status").map_err(mcap_err("add schema"))?;
        let tr = json_schema(&mut w, "s3tir.Trigger").map_err(mcap_err("add schema"))?;
        let cl = json_schema(&mut w, "s3tir.ClockMap").map_err(mcap_err("add schema"))?;
        let none = BTreeMap::new();
        let mut add = |schema, t: &str, enc: &str| w.add_channel(schema, t, enc, &none);
        let ch = Channels {
            thermal_image: add(img, topic::THERMAL_IMAGE, "ros1")
                .map_err(mcap_err("add channel"))?,
            thermal_meta: add(tm, topic::THERMAL_META, "json").map_err(mcap_err("add channel"))?,
            rgb_compressed: add(cmp, topic::RGB_COMPRESSED, "ros1")
                .map_err(mcap_err("add channel"))?,
            rgb_image: add(img, topic::RGB_IMAGE, "ros1").map_err(mcap_err("add channel"))?,
            rgb_meta: add(rm, topic::RGB_META, "json").map_err(mcap_err("add channel"))?,
            pairs: add(pr, topic::PAIRS, "json").map_err(mcap_err("add channel"))?,
            drops: add(dr, topic::DROPS, "json").map_err(mcap_err("add channel"))?,
            status: add(st, topic::STATUS, "json").map_err(mcap_err("add channel"))?,
            triggers: add(tr, topic::TRIGGERS, "json").map_err(mcap_err("add channel"))?,
            clock: add(cl, topic::CLOCK, "json").map_err(mcap_err("add channel"))?,
        };
        w.write_metadata(&mcap::records::Metadata {
            name: "s3tir.session".into(),
            metadata: info.to_map(),
        })
        .map_err(mcap_err("write metadata"))?;
        let mut me = Self {
            path: path.to_owned(),
            writer: Some(w),
            sync_handle,
            ch,
            last_flush: Instant::now(),
            last_sync: Instant::now(),
            bytes_in_chunk: 0,
            bytes_written: 0,
            flush_interval: FLUSH_INTERVAL,
            sync_interval: Some(SYNC_INTERVAL),
            syncs: SyncStats::default(),
        };
        me.flush()?;
        Ok(me)
    }

    /// Attaches a file (calibration) to the session.
    pub fn attach(
        &mut self,
        name: &str,
        media_type: &str,
        data: &[u8],
    ) -> Result<(), CaptureError> {
        let path = self.path.clone();
        let w = self.writer_mut()?;
        w.attach(&mcap::Attachment {
            log_time: 0,
            create_time: 0,
            name: name.into(),
            media_type: media_type.into(),
            data: std::borrow::Cow::Borrowed(data),
        })
        .map_err(|source| CaptureError::Mcap {
            path,
            what: "attach",
            source,
        })
    }

    fn writer_mut(&mut self) -> Result<&mut mcap::Writer<BufWriter<File>>, CaptureError> {
        let path = self.path.clone();
        self.writer.as_mut().ok_or(CaptureError::SessionIo {
            path,
            what: "write after finish",
            source: std::io::Error::other("session already finished"),
        })
    }

    fn put(
        &mut self,
        channel: u16,
        seq: u32,
        log: u64,
        publish: u64,
        data: &[u8],
    ) -> Result<(), CaptureError> {
        let path = self.path.clone();
        let w = self.writer_mut()?;
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: channel,
                sequence: seq,
                log_time: log,
                publish_time: publish,
            },
            data,
        )
        .map_err(|source| CaptureError::Mcap {
            path,
            what: "write message",
            source,
        })?;
        self.bytes_in_chunk += data.len();
        self.bytes_written += data.len() as u64;
        Ok(())
    }

    fn json<T: Serialize>(&self, v: &T) -> Result<Vec<u8>, CaptureError> {
        serde_json::to_vec(v).map_err(|e| CaptureError::SessionIo {
            path: self.path.clone(),
            what: "encode JSON",
            source: std::io::Error::other(e),
        })
    }

    /// Writes one record; ends the chunk afterwards when it is due.
    pub fn write(&mut self, rec: &SessionRecord) -> Result<(), CaptureError> {
        let ch = self.ch;
        match rec {
            SessionRecord::Frame {
                frame: CapturedFrame::Thermal(f),
                ffc_hint,
            } => {
                let t = f.time;
                let meta = ThermalMeta {
                    sequence: t.sequence,
                    monotonic_ns: t.monotonic_ns,
                    wall_unix_ns: t.wall_unix_ns,
                    width: f.width,
                    height: f.height,
                    units: f.units,
                    ffc: f.ffc,
                    ffc_hint: *ffc_hint,
                    telemetry_rows: if f.width == 0 {
                        0
                    } else {
                        (f.telemetry_words.len() / f.width as usize) as u32
                    },
                    telemetry_words: f.telemetry_words.clone(),
                    telemetry: f.telemetry,
                };
                let m = self.json(&meta)?;
                self.put(
                    ch.thermal_meta,
                    t.sequence,
                    t.wall_unix_ns,
                    t.monotonic_ns,
                    &m,
                )?;
                let mut data = Vec::with_capacity(f.pixels.len() * 2);
                for p in &f.pixels {
                    data.extend_from_slice(&p.to_le_bytes());
                }
                let img = encode_ros_image(
                    &RosImage {
                        seq: t.sequence,
                        width: f.width,
                        height: f.height,
                        encoding: "mono16",
                        step: f.width * 2,
                        data: &data,
                    },
                    t.wall_unix_ns,
                    "thermal",
                );
                self.put(
                    ch.thermal_image,
                    t.sequence,
                    t.wall_unix_ns,
                    t.monotonic_ns,
                    &img,
                )?;
            }
            SessionRecord::Frame {
                frame: CapturedFrame::Rgb(f),
                ..
            } => {
                let t = f.time;
                let (fourcc, channel, msg) = match &f.payload {
                    RgbPayload::Mjpeg(b) => (
                        FourCc::MJPG,
                        ch.rgb_compressed,
                        encode_ros_compressed(t.sequence, t.wall_unix_ns, "rgb", b),
                    ),
                    RgbPayload::Yuyv(b) => (
                        FourCc::YUYV,
                        ch.rgb_image,
                        encode_ros_image(
                            &RosImage {
                                seq: t.sequence,
                                width: f.width,
                                height: f.height,
                                encoding: "yuv422_yuy2",
                                step: f.width * 2,
                                data: b,
                            },
                            t.wall_unix_ns,
                            "rgb",
                        ),
                    ),
                };
                let meta = RgbMeta {
                    sequence: t.sequence,
                    monotonic_ns: t.monotonic_ns,
                    wall_unix_ns: t.wall_unix_ns,
                    fourcc,
                    width: f.width,
                    height: f.height,
                };
                let m = self.json(&meta)?;
                self.put(ch.rgb_meta, t.sequence, t.wall_unix_ns, t.monotonic_ns, &m)?;
                self.put(channel, t.sequence, t.wall_unix_ns, t.monotonic_ns, &msg)?;
            }
            SessionRecord::Pair(p) => {
                let m = self.json(p)?;
                let t = p.thermal_monotonic_ns.max(p.rgb_monotonic_ns);
                self.put(ch.pairs, p.rgb_sequence, t, t, &m)?;
            }
            SessionRecord::Drop(d) => {
                let m = self.json(d)?;
                self.put(
                    ch.drops,
                    d.after_sequence,
                    d.monotonic_ns,
                    d.monotonic_ns,
                    &m,
                )?;
            }
            SessionRecord::Status(s) => {
                let m = self.json(s)?;
                self.put(ch.status, 0, s.wall_unix_ns, s.wall_unix_ns, &m)?;
            }
            SessionRecord::Trigger(t) => {
                let m = self.json(t)?;
                self.put(ch.triggers, t.count, t.controller_ns, t.controller_ns, &m)?;
            }
            SessionRecord::Clock(c) => {
                let m = self.json(c)?;
                self.put(ch.clock, c.matched as u32, 0, c.mono_anchor_ns, &m)?;
            }
        }
        self.tick()
    }

    /// Ends the chunk if [`FLUSH_INTERVAL`] has passed or it is large. Cheap otherwise.
    pub fn tick(&mut self) -> Result<(), CaptureError> {
        if self.bytes_in_chunk > 0
            && (self.last_flush.elapsed() >= self.flush_interval
                || self.bytes_in_chunk >= MAX_CHUNK_BYTES)
        {
            self.flush()?;
        }
        Ok(())
    }

    /// Ends the current chunk and flushes it to the file; `fdatasync`s it when
    /// [`SYNC_INTERVAL`] has passed since the last sync.
    pub fn flush(&mut self) -> Result<(), CaptureError> {
        let path = self.path.clone();
        self.writer_mut()?
            .flush()
            .map_err(|source| CaptureError::Mcap {
                path,
                what: "flush chunk",
                source,
            })?;
        self.bytes_in_chunk = 0;
        self.last_flush = Instant::now();
        if self
            .sync_interval
            .is_some_and(|every| self.last_sync.elapsed() >= every)
        {
            self.sync()?;
        }
        Ok(())
    }

    /// Sets how often a chunk end waits for the disk; `None` never does: only for the bench's
    /// reference run, which measures what the syncs cost (a recording without syncs can lose
    /// anything in the page cache to a power cut).
    pub fn set_sync_interval(&mut self, every: Option<Duration>) {
        self.sync_interval = every;
    }

    /// Waits until everything flushed so far is on the storage device (`fdatasync`).
    pub fn sync(&mut self) -> Result<(), CaptureError> {
        let t = Instant::now();
        self.sync_handle
            .sync_data()
            .map_err(|source| CaptureError::SessionIo {
                path: self.path.clone(),
                what: "sync",
                source,
            })?;
        let took = t.elapsed();
        self.syncs.count += 1;
        self.syncs.total += took;
        self.syncs.max = self.syncs.max.max(took);
        self.last_sync = Instant::now();
        Ok(())
    }

    /// The `fdatasync`s so far.
    pub fn sync_stats(&self) -> SyncStats {
        self.syncs
    }

    /// Payload bytes written so far (before compression).
    pub fn bytes_written(&self) -> u64 {
        self.bytes_written
    }

    /// Writes the summary and footer and closes the file.
    pub fn finish(mut self) -> Result<(), CaptureError> {
        let path = self.path.clone();
        if let Some(mut w) = self.writer.take() {
            w.finish().map_err(|source| CaptureError::Mcap {
                path: path.clone(),
                what: "finish",
                source,
            })?;
            let mut inner = w.into_inner();
            std::io::Write::flush(&mut inner).map_err(|source| CaptureError::SessionIo {
                path,
                what: "flush",
                source,
            })?;
            if self.sync_interval.is_some() {
                self.sync()?;
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------- reader

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
    Clock(crate::clock_sync::ClockMap),
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
    let io = |what: &'static str| {
        move |source| CaptureError::SessionIo {
            path: path.to_owned(),
            what,
            source,
        }
    };
    let mut file = File::open(path).map_err(io("open"))?;
    let file_len = file.metadata().map_err(io("stat"))?.len();
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_emit_chunks(true)
            // A chunk in progress when the recorder died still carries the writer's
            // placeholder length (it is patched when the chunk ends): the limit turns it into
            // a clean "record too large" stop instead of an overflow.
            .with_record_length_limit(MAX_RECORD_BYTES),
    );
    let mut out = ReadOutcome::default();
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    let mut pending_thermal: Option<ThermalMeta> = None;
    let mut pending_rgb: Option<RgbMeta> = None;
    let mut saw_footer = false;
    // Where reading stopped: the offset of the record that could not be read, and why.
    let mut stop: Option<(u64, String)> = None;
    // Offset of the next file-level record (after the 8-byte magic).
    let mut offset: u64 = MAGIC_LEN;
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(e) => e,
            Err(e) => {
                stop = Some((offset, format!("{e}")));
                break;
            }
        };
        match event {
            LinearReadEvent::ReadRequest(n) => {
                let buf = reader.insert(n);
                let got = loop {
                    match file.read(buf) {
                        Ok(k) => break k,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                        Err(source) => return Err(io("read")(source)),
                    }
                };
                reader.notify_read(got);
            }
            LinearReadEvent::Record { data, opcode } => {
                let record_offset = offset;
                offset += RECORD_PREFIX_LEN + data.len() as u64;
                let record = match mcap::parse_record(opcode, data) {
                    Ok(r) => r,
                    Err(e) => {
                        stop = Some((
                            record_offset,
                            format!("corrupt record (opcode {opcode:#04x}): {e}"),
                        ));
                        break;
                    }
                };
                let mut handle = |rec: Record<'_>,
                                  topics: &mut BTreeMap<u16, String>|
                 -> Result<(), CaptureError> {
                    match rec {
                        Record::Channel(c) => {
                            topics.insert(c.id, c.topic);
                        }
                        Record::Message { header, data } => {
                            let t = topics.get(&header.channel_id).cloned().unwrap_or_default();
                            if let Some(item) = decode_message(
                                path,
                                &t,
                                header.sequence,
                                &data,
                                &mut pending_thermal,
                                &mut pending_rgb,
                            )? {
                                visit(item)?;
                            }
                        }
                        Record::Metadata(m) if m.name == "s3tir.session" => {
                            out.info = SessionInfo::from_map(&m.metadata);
                        }
                        Record::Attachment { header, data, .. } => {
                            out.attachments.insert(header.name, data.into_owned());
                        }
                        Record::Footer(_) => saw_footer = true,
                        _ => {}
                    }
                    Ok(())
                };
                match record {
                    Record::Chunk { header, data } => {
                        // Decompress the whole chunk before handing out anything from it, so
                        // a damaged chunk contributes nothing.
                        match decode_chunk(&header, &data) {
                            Ok(body) => {
                                let recs = match split_chunk(&body) {
                                    Ok(recs) => recs,
                                    Err(reason) => {
                                        stop = Some((
                                            record_offset,
                                            format!("corrupt chunk: {reason}"),
                                        ));
                                        break;
                                    }
                                };
                                out.chunks += 1;
                                for r in recs {
                                    handle(r, &mut topics)?;
                                }
                            }
                            Err(reason) => {
                                stop = Some((record_offset, format!("corrupt chunk: {reason}")));
                                break;
                            }
                        }
                    }
                    other => handle(other, &mut topics)?,
                }
            }
        }
    }
    if let Some((at, reason)) = stop {
        out.truncated = true;
        if is_cut(&file, file_len, at).map_err(io("read"))? {
            out.truncation_reason = Some(reason);
        } else {
            out.truncation_reason = Some(format!("damaged at byte {at}: {reason}"));
            out.damage = Some(Damage { offset: at, reason });
        }
    } else if !saw_footer {
        out.truncated = true;
        out.truncation_reason = Some("file ends without a footer".into());
    }
    Ok(out)
}

/// MCAP's magic (`\x89MCAP0\r\n`) before the first record.
const MAGIC_LEN: u64 = 8;
/// A record's opcode byte and u64 length.
const RECORD_PREFIX_LEN: u64 = 9;

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

/// Decompresses one chunk's records and checks its CRC. Every claimed size is checked against
/// [`MAX_RECORD_BYTES`] and the bytes really present before memory is reserved for it.
pub fn decode_chunk(header: &mcap::records::ChunkHeader, data: &[u8]) -> Result<Vec<u8>, String> {
    let claimed = header.uncompressed_size;
    if data.len() as u64 != header.compressed_size {
        return Err(format!(
            "header says {} compressed bytes, the record holds {}",
            header.compressed_size,
            data.len()
        ));
    }
    if claimed > MAX_RECORD_BYTES as u64 {
        return Err(format!(
            "claims {claimed} uncompressed bytes, more than the {MAX_RECORD_BYTES}-byte limit"
        ));
    }
    let body = match header.compression.as_str() {
        "" => {
            if claimed != data.len() as u64 {
                return Err(format!(
                    "uncompressed chunk of {} bytes claims {claimed}",
                    data.len()
                ));
            }
            data.to_vec()
        }
        "lz4" => {
            if claimed > (data.len() as u64).saturating_mul(LZ4_MAX_RATIO) {
                return Err(format!(
                    "claims {claimed} bytes from {} LZ4 bytes (LZ4 expands at most {LZ4_MAX_RATIO}x)",
                    data.len()
                ));
            }
            let mut body = Vec::with_capacity(claimed as usize);
            let decoder = lz4::Decoder::new(data).map_err(|e| format!("lz4: {e}"))?;
            // One byte more than claimed is read so a longer stream is seen, not cut.
            decoder
                .take(claimed + 1)
                .read_to_end(&mut body)
                .map_err(|e| format!("lz4: {e}"))?;
            if body.len() as u64 != claimed {
                return Err(format!(
                    "decompresses to {} bytes, the header claims {claimed}",
                    body.len()
                ));
            }
            body
        }
        other => return Err(format!("compression {other:?} (sessions use lz4)")),
    };
    if header.uncompressed_crc != 0 {
        let crc = crc32fast::hash(&body);
        if crc != header.uncompressed_crc {
            return Err(format!(
                "CRC {crc:#010x} of the records, the header says {:#010x}",
                header.uncompressed_crc
            ));
        }
    }
    Ok(body)
}

/// Splits a decompressed chunk into records; a record claiming more bytes than the chunk has
/// left is an error, not an allocation.
pub fn split_chunk(body: &[u8]) -> Result<Vec<Record<'static>>, String> {
    let mut recs = Vec::new();
    let mut rest = body;
    let mut at = 0usize;
    while !rest.is_empty() {
        let Some((&opcode, tail)) = rest.split_first() else {
            break;
        };
        let Some((len, tail)) = tail.split_first_chunk::<8>() else {
            return Err(format!(
                "record header at chunk byte {at} cut ({} bytes left)",
                rest.len()
            ));
        };
        let len = u64::from_le_bytes(*len);
        if len > tail.len() as u64 {
            return Err(format!(
                "record (opcode {opcode:#04x}) at chunk byte {at} claims {len} bytes, {} are left",
                tail.len()
            ));
        }
        let (data, tail) = tail.split_at(len as usize);
        let rec = mcap::parse_record(opcode, data)
            .map_err(|e| format!("record (opcode {opcode:#04x}) at chunk byte {at}: {e}"))?;
        recs.push(rec.into_owned());
        at += RECORD_PREFIX_LEN as usize + data.len();
        rest = tail;
    }
    Ok(recs)
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
    fn json<T: for<'a> Deserialize<'a>>(data: &[u8]) -> Result<T, String> {
        serde_json::from_slice(data).map_err(|e| e.to_string())
    }
    Ok(match topic_name {
        topic::THERMAL_META => {
            *pending_thermal = Some(json(data).map_err(bad)?);
            None
        }
        topic::RGB_META => {
            *pending_rgb = Some(json(data).map_err(bad)?);
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
        topic::PAIRS => Some(SessionItem::Pair(json(data).map_err(bad)?)),
        topic::DROPS => Some(SessionItem::Drop(json(data).map_err(bad)?)),
        topic::STATUS => Some(SessionItem::Status(json(data).map_err(bad)?)),
        topic::TRIGGERS => Some(SessionItem::Trigger(json(data).map_err(bad)?)),
        topic::CLOCK => Some(SessionItem::Clock(json(data).map_err(bad)?)),
        _ => None,
    })
}

/// The last frames of one stream as read from a session, for looking up the frames a `/pairs`
/// record names. Bounded and keyed by *arrival*, not by sequence: after a device reopen the
/// sequence restarts at 0, so evicting the smallest sequence (a map's first key) would throw
/// away the newest frames. A lookup returns the newest frame with that sequence (a pair
/// record follows its frames closely).
#[derive(Debug, Clone)]
pub struct FrameWindow<T> {
    capacity: usize,
    frames: std::collections::VecDeque<(u32, T)>,
}

impl<T> Default for FrameWindow<T> {
    fn default() -> Self {
        Self::new(Self::DEFAULT_CAPACITY)
    }
}

impl<T> FrameWindow<T> {
    /// Pairs are decided within a few frames; 512 covers seconds of the fastest stream.
    pub const DEFAULT_CAPACITY: usize = 512;

    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            frames: std::collections::VecDeque::new(),
        }
    }

    /// Adds the newest frame, forgetting the oldest beyond the capacity.
    pub fn push(&mut self, sequence: u32, frame: T) {
        if self.frames.len() == self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back((sequence, frame));
    }

    /// The newest frame with this sequence.
    pub fn get(&self, sequence: u32) -> Option<&T> {
        self.frames
            .iter()
            .rev()
            .find(|(s, _)| *s == sequence)
            .map(|(_, f)| f)
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

/// Numbers each stream's frames in file order: the recorded sequence while it increases,
/// continued (last + 1, …) when it goes back, as after a device reopen. Deterministic, so the
/// scan and every later read of the same file agree. Feed it every frame of the file.
#[derive(Debug, Clone, Copy, Default)]
pub struct SessionSequences {
    /// Per stream (thermal, RGB): the last recorded sequence and the number it was given.
    last: [Option<(u32, u32)>; 2],
    /// Added to recorded sequences since the last restart.
    offset: [u32; 2],
}

impl SessionSequences {
    /// The session sequence of the next frame of `stream` recorded with `sequence`.
    pub fn next(&mut self, stream: StreamKind, sequence: u32) -> u32 {
        let k = usize::from(stream == StreamKind::Rgb);
        if let Some((raw, given)) = self.last[k]
            && sequence <= raw
        {
            self.offset[k] = given.saturating_add(1).saturating_sub(sequence);
        }
        let id = sequence.saturating_add(self.offset[k]);
        self.last[k] = Some((sequence, id));
        id
    }
}

/// Convenience for tests and tools: the frame a recorded item parses to.
pub fn parse_recorded(path: &Path, f: &RecordedFrame) -> Result<CapturedFrame, CaptureError> {
    CapturedFrame::from_raw(&path.display().to_string(), &f.raw, f.wall_unix_ns)
}

#[cfg(test)]
mod tests {
    //! Proves: a session written through the pipeline reads back frame-for-frame byte-exact
    //! (device buffers rebuilt identically, pairs/drops/status kept), metadata and attachments
    //! survive, and a file cut at any byte reads back up to its last complete chunk, reports
    //! `truncated` (a cut, never damage), and never returns a frame that was not written; an
    //! existing file (a replay's own input included) is never overwritten; chunk ends
    //! `fdatasync` at most once per interval. Does not test a real SIGKILL
    //! (tests/tests/capture_recording.rs does, and bounds the loss) nor crafted chunks
    //! (tests/hostile_sessions.rs).
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::pairing::PairingMode;
    use crate::pipeline::Pipeline;
    use crate::synth::{Script, SynthRig, ThermalSynth};

    /// Returns the frames written and (file size, frames written) at each explicit flush.
    fn record(
        path: &Path,
        n: usize,
        flush_every: usize,
    ) -> (Vec<RecordedFrame>, Vec<(u64, usize)>) {
        let script = Script {
            ffc_frames: vec![4, 5],
            thermal_drops: vec![7],
            rgb_corrupt: vec![2],
            ..Script::default()
        };
        let mut rig =
            SynthRig::new(ThermalSynth::lepton35(), Some((32, 24, 9.0)), script, 1_000).unwrap();
        let info = SessionInfo {
            tool: "test".into(),
            thermal_device: "synthetic".into(),
            ..SessionInfo::default()
        };
        let mut w = SessionWriter::create(path, &info).unwrap();
        w.attach("calibration", "application/toml", b"fx = 1.0")
            .unwrap();
        let mut pipe = Pipeline::new(PairingMode::Nearest {
            tolerance_ns: 20_000_000,
        });
        let mut frames = Vec::new();
        let mut flush_sizes = Vec::new();
        for k in 0..n {
            let Some(raw) = rig.next_buffer() else {
                continue;
            };
            let wall = 1_700_000_000_000_000_000 + raw.monotonic_ns;
            let Ok(recs) = pipe.push("synthetic", &raw, wall) else {
                continue;
            };
            frames.push(RecordedFrame {
                raw,
                wall_unix_ns: wall,
            });
            for r in &recs {
                w.write(r).unwrap();
            }
            if k % flush_every == flush_every - 1 {
                w.flush().unwrap();
                flush_sizes.push((std::fs::metadata(path).unwrap().len(), frames.len()));
            }
        }
        for r in pipe.finish() {
            w.write(&r).unwrap();
        }
        w.finish().unwrap();
        (frames, flush_sizes)
    }

    fn read_frames(path: &Path) -> (Vec<RecordedFrame>, ReadOutcome, usize) {
        let mut frames = Vec::new();
        let mut pairs = 0;
        let out = read_session(path, |item| {
            match item {
                SessionItem::Frame(f) => frames.push(f),
                SessionItem::Pair(_) => pairs += 1,
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        (frames, out, pairs)
    }

    #[test]
    fn complete_session_reads_back_byte_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let (written, _) = record(&path, 40, 5);
        let (read, out, pairs) = read_frames(&path);
        assert!(!out.truncated, "complete file: {:?}", out.truncation_reason);
        assert_eq!(read.len(), written.len(), "frame count");
        for (a, b) in read.iter().zip(&written) {
            assert_eq!(a, b, "frame {} {:?} differs", a.raw.sequence, a.raw.stream);
        }
        assert!(pairs > 0, "pairs recorded");
        assert_eq!(out.info.thermal_device, "synthetic");
        assert_eq!(out.attachments.get("calibration").unwrap(), b"fx = 1.0");
    }

    /// A reopened device restarts at 0: its frames continue the stream's session numbering
    /// (no two frames share a name); the other stream is untouched; a second restart continues
    /// again.
    #[test]
    fn session_sequences_continue_past_a_restart() {
        use crate::frame::StreamKind::{Rgb, Thermal};
        let mut ids = SessionSequences::default();
        let got: Vec<u32> = [
            (Thermal, 5),
            (Rgb, 100),
            (Thermal, 6),
            (Thermal, 9),
            (Thermal, 0),
        ]
        .into_iter()
        .chain([(Thermal, 1), (Rgb, 101), (Thermal, 0), (Thermal, 3)])
        .map(|(s, q)| ids.next(s, q))
        .collect();
        assert_eq!(got, [5, 100, 6, 9, 10, 11, 101, 12, 15]);
    }

    #[test]
    fn an_existing_file_is_never_overwritten() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        record(&path, 10, 5);
        let before = std::fs::read(&path).unwrap();
        match SessionWriter::create(&path, &SessionInfo::default()) {
            Err(CaptureError::SessionExists { path: p }) => assert_eq!(p, path),
            other => panic!("creating over an existing session must be refused, got {other:?}"),
        }
        // `replay s.mcap --out s.mcap` would have truncated its own input.
        let r = crate::tools::replay(&path, Some(&path), false, None, |_| {});
        assert!(
            matches!(r, Err(CaptureError::SessionExists { .. })),
            "replay onto its input must be refused: {r:?}"
        );
        assert_eq!(
            std::fs::read(&path).unwrap(),
            before,
            "the existing session is untouched"
        );
    }

    #[test]
    fn chunk_ends_sync_the_file_at_most_once_per_interval() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sync.mcap");
        let mut w = SessionWriter::create(&path, &SessionInfo::default()).unwrap();
        let mut rig = SynthRig::new(ThermalSynth::lepton35(), None, Script::default(), 0).unwrap();
        let mut pipe = Pipeline::new(PairingMode::TriggerCounter);
        // Chunk ends back to back: none is due a sync yet.
        for _ in 0..5 {
            let raw = rig.next_buffer().unwrap();
            for r in pipe.push("t", &raw, 0).unwrap() {
                w.write(&r).unwrap();
            }
            w.flush().unwrap();
        }
        assert_eq!(w.sync_stats().count, 0, "five chunk ends within a second");
        // A chunk end after the interval syncs.
        w.last_sync -= SYNC_INTERVAL;
        w.flush().unwrap();
        assert_eq!(w.sync_stats().count, 1, "one sync once the interval passed");
        w.finish().unwrap();
        // The bench's reference writer never syncs, not even at the end.
        let path = dir.path().join("nosync.mcap");
        let mut w = SessionWriter::create(&path, &SessionInfo::default()).unwrap();
        w.set_sync_interval(None);
        w.last_sync -= SYNC_INTERVAL;
        w.flush().unwrap();
        assert_eq!(w.sync_stats().count, 0, "sync turned off");
    }

    #[test]
    fn cut_file_reads_to_last_complete_chunk() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let (written, flush_sizes) = record(&path, 40, 5);
        let bytes = std::fs::read(&path).unwrap();
        let cut_path = dir.path().join("cut.mcap");
        // 150 cuts spread over the file, plus every flush boundary ±1.
        let mut cuts: Vec<usize> = (0..bytes.len()).step_by(bytes.len() / 150 + 1).collect();
        for &(s, _) in &flush_sizes {
            cuts.extend([s as usize - 1, s as usize, s as usize + 1]);
        }
        for cut in cuts {
            let cut = cut.min(bytes.len() - 1);
            std::fs::write(&cut_path, &bytes[..cut]).unwrap();
            let (read, out, _) = read_frames(&cut_path);
            assert!(
                out.truncated,
                "cut at {cut} of {} must say truncated",
                bytes.len()
            );
            assert!(
                out.damage.is_none(),
                "cut at {cut} is a cut, not damage: {:?}",
                out.damage
            );
            assert!(read.len() <= written.len());
            for (a, b) in read.iter().zip(&written) {
                assert_eq!(a, b, "cut at {cut}: a frame that was not written");
            }
            // Everything flushed before the cut is read.
            let flushed = flush_sizes
                .iter()
                .filter(|&&(size, _)| size as usize <= cut)
                .map(|&(_, n)| n)
                .max()
                .unwrap_or(0);
            assert!(
                read.len() >= flushed,
                "cut at {cut}: read {} frames, {flushed} were flushed before the cut",
                read.len()
            );
        }
    }

    #[test]
    fn writer_dying_mid_chunk_leaves_a_readable_prefix() {
        // The kill -9 case: the chunk in progress is partly on disk (the 1 MB write buffer
        // spilled) with its length not yet patched. Forgetting the writer = no destructor runs.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("dying.mcap");
        let mut rig = SynthRig::new(ThermalSynth::lepton35(), None, Script::default(), 0).unwrap();
        let mut w = SessionWriter::create(&path, &SessionInfo::default()).unwrap();
        w.flush_interval = Duration::from_secs(3600);
        let mut pipe = Pipeline::new(PairingMode::TriggerCounter);
        for k in 0..100 {
            let raw = rig.next_buffer().unwrap();
            for r in pipe.push("t", &raw, 0).unwrap() {
                w.write(&r).unwrap();
            }
            if k == 9 {
                w.flush().unwrap();
            }
        }
        std::mem::forget(w);
        let on_disk = std::fs::metadata(&path).unwrap().len();
        assert!(
            on_disk > 2_000_000,
            "part of the open chunk reached the file: {on_disk} bytes"
        );
        let (read, out, _) = read_frames(&path);
        assert!(out.truncated, "must say truncated");
        assert!(
            out.damage.is_none(),
            "a dying writer is a cut: {:?}",
            out.damage
        );
        assert_eq!(read.len(), 10, "exactly the frames of the flushed chunk");
    }

    #[test]
    fn yuyv_frames_round_trip_with_row_padding_removed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("yuyv.mcap");
        let (w, h) = (4u32, 2u32);
        // 12 bytes per row: 8 of pixels + 4 of driver padding.
        let payload: Vec<u8> = (0..24u8).collect();
        let raw = RawFrame {
            stream: StreamKind::Rgb,
            fourcc: FourCc::YUYV,
            width: w,
            height: h,
            bytes_per_line: 12,
            telemetry_rows: 0,
            units: ThermalUnits::RawCounts,
            ffc_hint: FfcState::Unknown,
            sequence: 9,
            monotonic_ns: 77,
            payload,
        };
        let mut w_ = SessionWriter::create(&path, &SessionInfo::default()).unwrap();
        let mut pipe = Pipeline::new(PairingMode::TriggerCounter);
        for r in pipe.push("cam", &raw, 5).unwrap() {
            w_.write(&r).unwrap();
        }
        w_.finish().unwrap();
        let (read, out, _) = read_frames(&path);
        assert!(!out.truncated);
        assert_eq!(read.len(), 1);
        let f = &read[0].raw;
        assert_eq!(
            (f.fourcc, f.bytes_per_line, f.sequence),
            (FourCc::YUYV, 8, 9)
        );
        let want: Vec<u8> = (0..8u8).chain(12..20).collect();
        assert_eq!(
            f.payload, want,
            "packed rows, padding dropped, bytes untouched"
        );
    }
}
