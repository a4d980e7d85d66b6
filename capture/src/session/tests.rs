//! Proves: a session written through the pipeline reads back frame-for-frame byte-exact
//! (device buffers rebuilt identically, pairs/drops/status kept), metadata and attachments
//! survive, and a file cut at any byte reads back up to its last complete chunk, reports
//! `truncated` (a cut, never damage), and never returns a frame that was not written; an
//! existing file (a replay's own input included) is never overwritten; chunk ends
//! `fdatasync` at most once per interval. Does not test a real SIGKILL
//! (tests/tests/capture_recording.rs does, and bounds the loss) nor crafted chunks
//! (tests/hostile_sessions.rs).
#![allow(clippy::unwrap_used)]
use std::path::Path;
use std::time::Duration;

use crate::CaptureError;
use crate::backend::synth::{Script, SynthRig, ThermalSynth};
use crate::device::FourCc;
use crate::frame::{FfcState, RawFrame, StreamKind, ThermalUnits};
use crate::session::pairing::PairingMode;
use crate::session::pipeline::Pipeline;
use crate::session::*;

/// Returns the frames written and (file size, frames written) at each explicit flush.
fn record(path: &Path, n: usize, flush_every: usize) -> (Vec<RecordedFrame>, Vec<(u64, usize)>) {
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
