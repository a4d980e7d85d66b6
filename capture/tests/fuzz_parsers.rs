//! Property tests over everything capture parses from files and wires, fed hostile input:
//! MCAP sessions mutated at the byte level (overwrites, cuts, inserted bytes, chunk headers
//! with random sizes), simwire frames with random headers and lengths, V4L2-shaped buffers with
//! random geometry (Y16, YUYV, MJPEG; zero and overflowing sizes) and Lepton telemetry rows.
//! Each property asserts the parser returns (`Ok` or a typed error) without panicking, and, for
//! sessions, that nothing read is invented: every frame read from a mutated file that parses
//! is a frame of the original. Cases per property: `FUZZ_CASES` (256) in `make test`; raise
//! with `PROPTEST_CASES=N` for a longer run (capture/README.md gives the figures of one).
//! nightly-only `cargo fuzz` is not used: the project builds on stable, and these run in CI.
#![allow(clippy::unwrap_used)]

use std::io::Cursor;
use std::sync::OnceLock;

use proptest::prelude::*;
use s3tir_capture::backend::synth::{Script, SynthRig, ThermalSynth};
use s3tir_capture::device::FourCc;
use s3tir_capture::frame::{CapturedFrame, FfcState, RawFrame, StreamKind, ThermalUnits};
use s3tir_capture::session::pairing::PairingMode;
use s3tir_capture::session::pipeline::Pipeline;
use s3tir_capture::session::{
    RecordedFrame, SessionInfo, SessionItem, SessionWriter, decode_chunk, read_session, split_chunk,
};
use s3tir_capture::wire::simwire::WireFrame;

const FUZZ_CASES: u32 = 256;

fn cases() -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(FUZZ_CASES);
    ProptestConfig::with_cases(n)
}

/// A small valid session (Lepton + 32×24 MJPEG, a chunk every 4 buffers) and its frames.
fn session() -> &'static (Vec<u8>, Vec<RecordedFrame>) {
    static S: OnceLock<(Vec<u8>, Vec<RecordedFrame>)> = OnceLock::new();
    S.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let mut rig = SynthRig::new(
            ThermalSynth::lepton35(),
            Some((32, 24, 9.0)),
            Script::default(),
            0,
        )
        .unwrap();
        let mut w = SessionWriter::create(&path, &SessionInfo::default()).unwrap();
        let mut pipe = Pipeline::new(PairingMode::Nearest {
            tolerance_ns: 20_000_000,
        });
        let mut frames = Vec::new();
        for k in 0..16 {
            let raw = rig.next_buffer().unwrap();
            for r in pipe.push("fuzz", &raw, raw.monotonic_ns).unwrap() {
                w.write(&r).unwrap();
            }
            frames.push(RecordedFrame {
                wall_unix_ns: raw.monotonic_ns,
                raw,
            });
            if k % 4 == 3 {
                w.flush().unwrap();
            }
        }
        w.finish().unwrap();
        (std::fs::read(&path).unwrap(), frames)
    })
}

#[derive(Debug, Clone)]
enum Mutation {
    Overwrite {
        at: prop::sample::Index,
        byte: u8,
    },
    /// Eight bytes at once: a length or size field replaced by a random u64.
    Word {
        at: prop::sample::Index,
        word: u64,
    },
    Insert {
        at: prop::sample::Index,
        bytes: Vec<u8>,
    },
    Cut {
        at: prop::sample::Index,
    },
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<prop::sample::Index>(), any::<u8>())
            .prop_map(|(at, byte)| Mutation::Overwrite { at, byte }),
        (
            any::<prop::sample::Index>(),
            prop_oneof![any::<u64>(), 0u64..1 << 20, Just(u64::MAX)]
        )
            .prop_map(|(at, word)| Mutation::Word { at, word }),
        (
            any::<prop::sample::Index>(),
            prop::collection::vec(any::<u8>(), 1..32)
        )
            .prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        any::<prop::sample::Index>().prop_map(|at| Mutation::Cut { at }),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    match m {
        Mutation::Overwrite { at, byte } => {
            let i = at.index(bytes.len());
            bytes[i] = *byte;
        }
        Mutation::Word { at, word } => {
            let i = at.index(bytes.len().saturating_sub(8).max(1));
            let end = (i + 8).min(bytes.len());
            bytes[i..end].copy_from_slice(&word.to_le_bytes()[..end - i]);
        }
        Mutation::Insert { at, bytes: ins } => {
            let i = at.index(bytes.len() + 1);
            bytes.splice(i..i, ins.iter().copied());
        }
        Mutation::Cut { at } => {
            let i = at.index(bytes.len() + 1);
            bytes.truncate(i);
        }
    }
}

fn any_raw() -> impl Strategy<Value = RawFrame> {
    let size = prop_oneof![
        0u32..80,
        Just(u32::MAX),
        Just(u32::MAX / 2 + 1),
        any::<u32>()
    ];
    (
        prop_oneof![Just(StreamKind::Thermal), Just(StreamKind::Rgb)],
        prop_oneof![Just(FourCc::Y16), Just(FourCc::YUYV), Just(FourCc::MJPG)],
        size.clone(),
        size.clone(),
        size,
        prop_oneof![0u32..4, any::<u32>()],
        prop::collection::vec(any::<u8>(), 0..4096),
        any::<u32>(),
    )
        .prop_map(
            |(stream, fourcc, width, height, bytes_per_line, telemetry_rows, payload, sequence)| {
                RawFrame {
                    stream,
                    fourcc,
                    width,
                    height,
                    bytes_per_line,
                    telemetry_rows,
                    units: ThermalUnits::CentiKelvin,
                    ffc_hint: FfcState::Unknown,
                    sequence,
                    monotonic_ns: 0,
                    payload,
                }
            },
        )
}

proptest! {
    #![proptest_config(cases())]

    /// A mutated session reads without panicking; a read that succeeds returns only frames of
    /// the original (a damaged chunk contributes nothing: chunks carry CRCs), and a file left
    /// intact up to some byte keeps the frames of the chunks before it.
    #[test]
    fn mutated_sessions_never_panic_or_invent_frames(muts in prop::collection::vec(mutation(), 1..4)) {
        let (good, frames) = session();
        let mut bytes = good.clone();
        for m in &muts {
            apply(&mut bytes, m);
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.mcap");
        std::fs::write(&path, &bytes).unwrap();
        let mut read = Vec::new();
        let r = read_session(&path, |item| {
            if let SessionItem::Frame(f) = item {
                read.push(f);
            }
            Ok(())
        });
        if r.is_ok() {
            for f in &read {
                prop_assert!(
                    frames.contains(f),
                    "frame {} {:?} read from a mutated file is not one that was written",
                    f.raw.sequence,
                    f.raw.stream
                );
            }
        }
    }

    /// A chunk record with random header fields and body decodes or is refused; it never
    /// allocates what it claims before checking it.
    #[test]
    fn random_chunks_are_refused_or_decoded(
        uncompressed_size in prop_oneof![any::<u64>(), 0u64..4096],
        crc in any::<u32>(),
        lz4 in any::<bool>(),
        body in prop::collection::vec(any::<u8>(), 0..512),
    ) {
        let header = mcap::records::ChunkHeader {
            message_start_time: 0,
            message_end_time: 0,
            uncompressed_size,
            uncompressed_crc: crc,
            compression: if lz4 { "lz4".into() } else { String::new() },
            compressed_size: body.len() as u64,
        };
        if let Ok(decoded) = decode_chunk(&header, &body) {
            prop_assert_eq!(decoded.len() as u64, uncompressed_size);
            let _ = split_chunk(&decoded);
        }
        // The records splitter alone, on random bytes (CRC 0 skips the check).
        let _ = split_chunk(&body);
    }

    /// Random simwire streams: a typed error or a frame within the payload limit.
    #[test]
    fn random_simwire_streams_never_panic(
        header in prop::collection::vec(any::<u8>(), 0..64),
        tail in prop::collection::vec(any::<u8>(), 0..256),
        valid_prefix in any::<bool>(),
    ) {
        let mut bytes = header;
        if valid_prefix && bytes.len() >= 6 {
            bytes[0..4].copy_from_slice(b"S3WF");
            bytes[4..6].copy_from_slice(&1u16.to_le_bytes());
        }
        bytes.extend(tail);
        let mut c = Cursor::new(bytes);
        for _ in 0..4 {
            match WireFrame::read_from(&mut c, "fuzz") {
                Ok(Some(f)) => prop_assert!(f.payload.len() <= 64 << 20),
                Ok(None) | Err(_) => break,
            }
        }
    }

    /// Device buffers with random geometry (zero, huge, overflowing) and payloads parse or
    /// are refused as corrupt; a parsed thermal frame has exactly width × height pixels.
    #[test]
    fn random_device_buffers_never_panic(raw in any_raw()) {
        if let Ok(CapturedFrame::Thermal(t)) = CapturedFrame::from_raw("fuzz", &raw, 0) {
            prop_assert_eq!(t.pixels.len(), t.width as usize * t.height as usize);
        }
    }

    /// Lepton telemetry rows of any content and length decode or are refused.
    #[test]
    fn random_telemetry_rows_never_panic(words in prop::collection::vec(any::<u16>(), 0..400)) {
        let _ = s3tir_capture::telemetry::decode(&words);
    }
}
