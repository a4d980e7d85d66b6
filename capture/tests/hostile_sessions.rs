//! Proves: a session file with a crafted or damaged chunk (an inner record claiming exabytes,
//! a chunk claiming a terabyte or more than LZ4 can expand to, a bad CRC, a short stream) reads
//! up to the damage with bounded memory (a counting allocator measures the read's peak), names
//! the byte offset of the damaged record, and keeps every frame before it; a zero-filled tail
//! (what a power cut can leave) is a cut, not damage; `s3tir-capture info` on a damaged file
//! exits non-zero naming the file and the offset. Does not fuzz (the proptest in
//! `tests/fuzz_parsers.rs` does).
#![allow(clippy::unwrap_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use s3tir_capture::backend::synth::{Script, SynthRig, ThermalSynth};
use s3tir_capture::session::pairing::PairingMode;
use s3tir_capture::session::pipeline::Pipeline;
use s3tir_capture::session::{ReadOutcome, SessionInfo, SessionItem, SessionWriter, read_session};

/// Counts live heap bytes and their peak, so a test can bound what a read allocates.
struct Counting;
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let now = LIVE.fetch_add(new_size - layout.size(), Ordering::Relaxed)
                    + (new_size - layout.size());
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// The tests share the counters: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// Largest extra heap a read of these small files may use (they hold ~1 MB of frames).
const READ_HEAP_LIMIT: usize = 32 << 20;

/// Records a small session (Lepton frames + 32×24 RGB), ending a chunk every 5 frames.
/// Returns the file's bytes and, after each chunk, (file size, frames so far).
fn good_session(path: &Path) -> (Vec<u8>, Vec<(usize, usize)>) {
    let mut rig = SynthRig::new(
        ThermalSynth::lepton35(),
        Some((32, 24, 9.0)),
        Script::default(),
        1_000,
    )
    .unwrap();
    let mut w = SessionWriter::create(path, &SessionInfo::default()).unwrap();
    let mut pipe = Pipeline::new(PairingMode::Nearest {
        tolerance_ns: 20_000_000,
    });
    let mut frames = 0;
    let mut ends = Vec::new();
    for k in 0..30 {
        let raw = rig.next_buffer().unwrap();
        for r in pipe.push("synthetic", &raw, raw.monotonic_ns).unwrap() {
            w.write(&r).unwrap();
        }
        frames += 1;
        if k % 5 == 4 {
            w.flush().unwrap();
            ends.push((std::fs::metadata(path).unwrap().len() as usize, frames));
        }
    }
    w.finish().unwrap();
    (std::fs::read(path).unwrap(), ends)
}

/// A chunk record (opcode 0x06) with the given header fields around `compressed`.
fn chunk_record(uncompressed_size: u64, crc: u32, compression: &str, compressed: &[u8]) -> Vec<u8> {
    let mut body = Vec::new();
    body.extend_from_slice(&0u64.to_le_bytes()); // message start time
    body.extend_from_slice(&0u64.to_le_bytes()); // message end time
    body.extend_from_slice(&uncompressed_size.to_le_bytes());
    body.extend_from_slice(&crc.to_le_bytes());
    body.extend_from_slice(&(compression.len() as u32).to_le_bytes());
    body.extend_from_slice(compression.as_bytes());
    body.extend_from_slice(&(compressed.len() as u64).to_le_bytes());
    body.extend_from_slice(compressed);
    let mut rec = vec![0x06];
    rec.extend_from_slice(&(body.len() as u64).to_le_bytes());
    rec.extend_from_slice(&body);
    rec
}

fn lz4(data: &[u8]) -> Vec<u8> {
    let mut enc = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
    std::io::Write::write_all(&mut enc, data).unwrap();
    let (out, res) = enc.finish();
    res.unwrap();
    out
}

/// Reads `path`, returning the outcome, the frames read and the read's heap peak above what
/// was live before it.
fn read_measured(path: &Path) -> (ReadOutcome, usize, usize) {
    let before = LIVE.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let mut frames = 0;
    let out = read_session(path, |item| {
        if matches!(item, SessionItem::Frame(_)) {
            frames += 1;
        }
        Ok(())
    })
    .unwrap();
    let peak = PEAK.load(Ordering::Relaxed).saturating_sub(before);
    (out, frames, peak)
}

#[test]
fn crafted_and_damaged_chunks_stop_the_read_at_their_offset_with_bounded_memory() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let (good, ends) = good_session(&dir.path().join("good.mcap"));
    // The damage goes after the second chunk; the frames of the first two must survive.
    let (prefix_len, prefix_frames) = ends[1];
    let (_, baseline_frames, baseline_peak) = read_measured(&dir.path().join("good.mcap"));
    assert!(
        baseline_frames > prefix_frames,
        "the good file holds more frames"
    );

    // An inner record header claiming 2^60 bytes, in a chunk whose CRC is right.
    let mut exa = vec![0x05u8];
    exa.extend_from_slice(&(1u64 << 60).to_le_bytes());
    let records = lz4(&[7u8; 4096]);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "inner record claiming 2^60 bytes",
            chunk_record(9, crc32fast::hash(&exa), "", &exa),
            "claims 1152921504606846976 bytes",
        ),
        (
            "chunk claiming a terabyte",
            chunk_record(1 << 40, 1, "lz4", &records),
            "more than the",
        ),
        (
            "chunk claiming more than LZ4 can expand to",
            chunk_record(200 << 20, 1, "lz4", &[0u8; 16]),
            "LZ4 expands at most",
        ),
        (
            "chunk with a bad CRC",
            chunk_record(4096, crc32fast::hash(&[7u8; 4096]) ^ 1, "lz4", &records),
            "CRC",
        ),
        (
            "chunk decompressing to less than it claims",
            chunk_record(4097, 0, "lz4", &records),
            "decompresses to 4096 bytes",
        ),
        (
            "chunk in an unknown compression",
            chunk_record(4096, 0, "brotli", &records),
            "compression \"brotli\"",
        ),
    ];
    for (what, chunk, expect) in cases {
        let mut bytes = good[..prefix_len].to_vec();
        bytes.extend_from_slice(&chunk);
        // The rest of the good file after the damage: never read, but present (damage, not a cut).
        bytes.extend_from_slice(&good[prefix_len..]);
        let path = dir.path().join("crafted.mcap");
        std::fs::write(&path, &bytes).unwrap();
        let t = Instant::now();
        let (out, frames, peak) = read_measured(&path);
        let took = t.elapsed();
        let damage = out
            .damage
            .as_ref()
            .unwrap_or_else(|| panic!("{what}: must be reported as damage, got {out:?}"));
        assert_eq!(
            damage.offset, prefix_len as u64,
            "{what}: the damaged record starts at byte {prefix_len}"
        );
        assert!(
            damage.reason.contains(expect),
            "{what}: reason {:?} should say {expect:?}",
            damage.reason
        );
        assert!(out.truncated, "{what}: a damaged read is also truncated");
        assert_eq!(
            frames, prefix_frames,
            "{what}: every frame before the damage is read, none after"
        );
        assert!(
            peak < READ_HEAP_LIMIT.max(2 * baseline_peak),
            "{what}: the read's heap peaked at {peak} bytes (the good file's read: {baseline_peak})"
        );
        println!("{what}: stopped at byte {prefix_len} in {took:?}, heap peak {peak} bytes");
    }

    // A zero-filled tail after a complete chunk is what a power cut can leave: a cut.
    let mut zeros = good[..prefix_len].to_vec();
    zeros.extend(std::iter::repeat_n(0u8, 1 << 16));
    let path = dir.path().join("zero-tail.mcap");
    std::fs::write(&path, &zeros).unwrap();
    let (out, frames, _) = read_measured(&path);
    assert!(
        out.truncated && out.damage.is_none(),
        "a zero tail is a cut, not damage: {out:?}"
    );
    assert_eq!(
        frames, prefix_frames,
        "zero tail: the chunks before it are read"
    );
}

#[test]
fn info_on_a_damaged_file_fails_naming_the_file_and_offset() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let (good, ends) = good_session(&dir.path().join("good.mcap"));
    let (prefix_len, _) = ends[0];
    let mut exa = vec![0x05u8];
    exa.extend_from_slice(&u64::MAX.to_le_bytes());
    let mut bytes = good[..prefix_len].to_vec();
    bytes.extend_from_slice(&chunk_record(9, crc32fast::hash(&exa), "", &exa));
    bytes.extend_from_slice(&good[prefix_len..]);
    let path = dir.path().join("crafted.mcap");
    std::fs::write(&path, &bytes).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_s3tir-capture"))
        .arg("info")
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "info on a damaged file must exit non-zero; stderr: {stderr}"
    );
    assert!(
        stderr.contains(&path.display().to_string())
            && stderr.contains(&format!("damaged at byte {prefix_len}")),
        "stderr must name {} and byte {prefix_len}: {stderr}",
        path.display()
    );
    // The summary of what could be read is still printed.
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("TRUNCATED"), "stdout: {stdout}");

    // The good file is fine.
    let ok = std::process::Command::new(env!("CARGO_BIN_EXE_s3tir-capture"))
        .arg("info")
        .arg(dir.path().join("good.mcap"))
        .output()
        .unwrap();
    assert!(
        ok.status.success(),
        "info on the good file: {}",
        String::from_utf8_lossy(&ok.stderr)
    );
}
