//! [`SessionWriter`]: frames and records into a chunked, LZ4-compressed MCAP file, with chunk
//! ends at least every [`FLUSH_INTERVAL`] and `fdatasync` at most every [`SYNC_INTERVAL`].

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::MessageHeader;
use serde::Serialize;

use crate::device::FourCc;
use crate::error::CaptureError;
use crate::frame::{CapturedFrame, FfcState, RgbFrame, RgbPayload, ThermalFrame};
use crate::session::records::{RgbMeta, SessionInfo, SessionRecord, ThermalMeta, topic};
use crate::session::ros1::{
    RosImage, compressed_schema, encode_ros_compressed, encode_ros_image, image_schema,
};

/// Longest time between chunk ends (the most a crash loses).
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(500);
/// Longest time between `fdatasync`s of the session file (at a chunk end): with
/// [`FLUSH_INTERVAL`], the most a power cut loses is the last ~1.5 s.
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);
/// A chunk is also ended when it holds this many uncompressed bytes.
pub const MAX_CHUNK_BYTES: usize = 8 * 1024 * 1024;

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
    pub(super) last_sync: Instant,
    bytes_in_chunk: usize,
    bytes_written: u64,
    pub(super) flush_interval: Duration,
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
            } => self.write_thermal(f, *ffc_hint)?,
            SessionRecord::Frame {
                frame: CapturedFrame::Rgb(f),
                ..
            } => self.write_rgb(f)?,
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

    /// A thermal frame: its meta message (JSON), then the image (`mono16`, the pixels without
    /// the telemetry rows, which the meta message carries).
    fn write_thermal(&mut self, f: &ThermalFrame, ffc_hint: FfcState) -> Result<(), CaptureError> {
        let t = f.time;
        let meta = ThermalMeta {
            sequence: t.sequence,
            monotonic_ns: t.monotonic_ns,
            wall_unix_ns: t.wall_unix_ns,
            width: f.width,
            height: f.height,
            units: f.units,
            ffc: f.ffc,
            ffc_hint,
            telemetry_rows: if f.width == 0 {
                0
            } else {
                (f.telemetry_words.len() / f.width as usize) as u32
            },
            telemetry_words: f.telemetry_words.clone(),
            telemetry: f.telemetry,
        };
        let m = self.json(&meta)?;
        let ch = self.ch;
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
        )
    }

    /// An RGB frame: its meta message (JSON), then the image (MJPEG as a CompressedImage,
    /// YUYV as an Image).
    fn write_rgb(&mut self, f: &RgbFrame) -> Result<(), CaptureError> {
        let ch = self.ch;
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
        self.put(channel, t.sequence, t.wall_unix_ns, t.monotonic_ns, &msg)
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
