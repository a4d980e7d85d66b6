//! Sessions in MCAP (feature `session`): the format, its writer and crash-tolerant reader, and
//! the frame path that produces its records (drop detection, pairing, clock sync).
//!
//! Modules:
//! - [`records`]: topic names and the records a session holds ([`SessionRecord`], [`SessionInfo`]),
//! - [`ros1`]: the ROS 1 codec of the image messages,
//! - [`writer`]: [`SessionWriter`] (chunking, LZ4, flush and `fdatasync` cadence),
//! - [`chunk`]: chunk decompression and record splitting with checked sizes,
//! - [`reader`]: [`read_session`], the crash-tolerant streaming reader,
//! - [`sequences`]: following frames in file order ([`FrameWindow`], [`SessionSequences`]),
//! - [`pairing`]: thermal↔RGB pairing, drop detection, sync statistics,
//! - [`clock_sync`]: rig-controller clock → camera clock fit and trigger pairing,
//! - [`pipeline`]: parse → drop detection → pairing, the path of every frame, live or replayed.
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
//! Every length in a file is checked against what is really there before anything is allocated:
//! file-level records against [`MAX_RECORD_BYTES`], a chunk's claimed uncompressed size against
//! [`MAX_RECORD_BYTES`] and against what LZ4 can expand its compressed bytes to
//! ([`LZ4_MAX_RATIO`]), and each record inside a chunk against the bytes left in the chunk. Chunks
//! are decompressed and split by [`chunk`] ([`decode_chunk`]), not by `mcap::read::ChunkReader`,
//! which reserves an inner record's claimed length before any check (a 9-byte inner header could
//! ask for exabytes). A file that stops early is a *cut* (crash, kill, full disk: the normal case,
//! [`ReadOutcome::truncated`]); corrupt data that is all there (a bad CRC, an impossible length) is
//! *damage* ([`ReadOutcome::damage`], with its byte offset), which `s3tir-capture info` reports as
//! an error.

pub mod chunk;
pub mod clock_sync;
pub mod pairing;
pub mod pipeline;
pub mod reader;
pub mod records;
pub mod ros1;
pub mod sequences;
pub mod writer;

// The session's public names at `s3tir_capture::session::…`, where calib and the tools use them.
pub use chunk::{ChunkError, LZ4_MAX_RATIO, MAX_RECORD_BYTES, decode_chunk, split_chunk};
pub use pairing::{DropRecord, PairRecord};
pub use reader::{Damage, ReadOutcome, RecordedFrame, SessionItem, parse_recorded, read_session};
pub use records::{
    RgbMeta, SessionInfo, SessionRecord, StatusRecord, ThermalMeta, TriggerRecord, topic,
};
pub use ros1::{
    RosImage, decode_ros_compressed, decode_ros_image, encode_ros_compressed, encode_ros_image,
};
pub use sequences::{FrameWindow, SessionSequences};
pub use writer::{FLUSH_INTERVAL, MAX_CHUNK_BYTES, SYNC_INTERVAL, SessionWriter, SyncStats};

// The tests drive the writer with the synthetic rig (feature `rig`).
#[cfg(all(test, feature = "rig"))]
mod tests;
