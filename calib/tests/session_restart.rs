//! Proves: a session whose cameras were reopened mid-recording (sequence numbers restart at 0,
//! as after a USB re-enumeration or the capture daemon's stall watchdog) gives the session
//! calibration every recorded pair, those after the restart included, under distinct view
//! names (session sequences, continued past the restart) whose frames all load. Before, the
//! frame window was keyed by sequence and evicted the newest frames (the restarted, small
//! sequences) first, so every pair after the restart was "a frame not in the session". With `max_views`, the views kept are spread over the whole
//! session and only their pixels are held. The poses stage numbers the frames of such a
//! session past the restart (unique, increasing per stream), and the keyframes it writes are
//! the frames it scanned, on both sides of the restart; its scan reports one progress stage
//! (start, one event per frame, finish). Does not calibrate
//! (tests/session_input.rs does) nor run COLMAP (tests/tests/session_to_dataset.rs does).
#![allow(clippy::unwrap_used)]

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU64, Ordering};

use s3tir_calib::detect::board::Camera;
use s3tir_calib::detect::session::{SessionOptions, read_views};
use s3tir_calib::progress::Progress;
use s3tir_capture::backend::synth::{Script, SynthRig, ThermalSynth};
use s3tir_capture::session::pairing::PairingMode;
use s3tir_capture::session::pipeline::Pipeline;
use s3tir_capture::session::{SessionInfo, SessionItem, SessionWriter, read_session};

/// Writes a session whose devices are reopened after 900 buffers (600 thermal, 300 RGB: more
/// than the 512-frame windows) and number from 0 again for 150 more.
fn restarted_session(path: &std::path::Path) {
    let thermal = ThermalSynth {
        width: 32,
        height: 24,
        ..ThermalSynth::boson640()
    };
    let mut rig = SynthRig::new(thermal, Some((32, 24, 30.0)), Script::default(), 0).unwrap();
    let mut w = SessionWriter::create(path, &SessionInfo::default()).unwrap();
    let mut pipe = Pipeline::new(PairingMode::Nearest {
        tolerance_ns: 20_000_000,
    });
    for k in 0..1050 {
        if k == 900 {
            rig.restart_sequences();
        }
        let raw = rig.next_buffer().unwrap();
        for r in pipe.push("synthetic", &raw, raw.monotonic_ns).unwrap() {
            w.write(&r).unwrap();
        }
    }
    for r in pipe.finish() {
        w.write(&r).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn pairs_after_a_sequence_restart_are_all_views() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("restart.mcap");
    restarted_session(&path);

    let mut recorded = 0;
    read_session(&path, |item| {
        if let SessionItem::Pair(_) = item {
            recorded += 1;
        }
        Ok(())
    })
    .unwrap();
    assert!(recorded >= 340, "the session holds {recorded} pairs");

    let v = read_views(
        &path,
        &SessionOptions {
            min_interval_s: 0.0,
            max_views: 0,
        },
    )
    .unwrap();
    assert!(
        v.problems.is_empty(),
        "no pair may lose its frames: {:?}",
        v.problems.iter().take(3).collect::<Vec<_>>()
    );
    assert_eq!(v.views.len(), recorded, "every recorded pair is a view");
    let keys: BTreeSet<&str> = v.views.iter().map(|x| x.key.as_str()).collect();
    assert_eq!(keys.len(), v.views.len(), "view keys are distinct");
    // Views are keyed by the thermal frame's session sequence: the 600 thermal frames before
    // the restart are 0..=599, those after it continue from 600 (their recorded sequence is 0…).
    let seq = |key: &str| -> u32 { key.parse().unwrap() };
    let after = v.views.iter().filter(|x| seq(&x.key) >= 600).count();
    assert!(
        after >= 40,
        "the pairs after the restart continue the numbering: {after} views past 600"
    );
    assert!(
        v.views.windows(2).all(|w| seq(&w[1].key) > seq(&w[0].key)),
        "session sequences increase through the restart"
    );
    for view in &v.views {
        for (file, camera) in view.files.iter().zip([Camera::Thermal, Camera::Rgb]) {
            let file = file.as_ref().unwrap();
            v.images.load(file, camera).unwrap_or_else(|e| {
                panic!("view {}: {} does not load: {e}", view.key, file.display())
            });
        }
    }

    // At most 50 views, from the whole session (both sides of the restart), with a note.
    let capped = read_views(
        &path,
        &SessionOptions {
            min_interval_s: 0.0,
            max_views: 50,
        },
    )
    .unwrap();
    assert_eq!(capped.views.len(), 50, "capped at max_views");
    let seqs: Vec<u32> = capped.views.iter().map(|x| seq(&x.key)).collect();
    assert!(
        seqs.first().is_some_and(|s| *s < 100) && seqs.last().is_some_and(|s| *s >= 600),
        "the kept views spread over the whole session, both sides of the restart: {seqs:?}"
    );
    assert!(
        capped.notes.iter().any(|n| n.contains("50 of")),
        "the cap is noted: {:?}",
        capped.notes
    );
}

/// Counts the progress events it hears: (starts, items advanced, finishes).
#[derive(Debug, Default)]
struct Counting {
    starts: AtomicU64,
    advanced: AtomicU64,
    finishes: AtomicU64,
}

impl Progress for Counting {
    fn start(&self, _stage: &str, _total: Option<u64>) {
        self.starts.fetch_add(1, Ordering::Relaxed);
    }
    fn advance(&self, n: u64) {
        self.advanced.fetch_add(n, Ordering::Relaxed);
    }
    fn finish(&self) {
        self.finishes.fetch_add(1, Ordering::Relaxed);
    }
}

impl Counting {
    fn counts(&self) -> (u64, u64, u64) {
        (
            self.starts.load(Ordering::Relaxed),
            self.advanced.load(Ordering::Relaxed),
            self.finishes.load(Ordering::Relaxed),
        )
    }
}

#[test]
fn the_poses_stage_numbers_frames_past_a_restart() {
    use s3tir_calib::poses::frames::{Stream, scan_session, write_keyframes};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("restart.mcap");
    restarted_session(&path);
    let progress = Counting::default();
    let scan = scan_session(&path, &progress).unwrap();
    assert_eq!(
        progress.counts(),
        (1, (scan.thermal.len() + scan.rgb.len()) as u64, 1),
        "the scan reports one stage (start, every frame, finish)"
    );
    for (name, frames) in [("thermal", &scan.thermal), ("rgb", &scan.rgb)] {
        assert!(
            frames.windows(2).all(|w| w[1].sequence > w[0].sequence),
            "{name}: session sequences must increase through the restart"
        );
    }
    assert_eq!(scan.thermal.len(), 700, "every thermal frame scanned");
    // Keyframes on both sides of the restart (thermal 599 is the last before it, 600 the
    // first after), written under distinct names, each the frame the scan described.
    let picks: Vec<_> = scan
        .thermal
        .iter()
        .filter(|f| [10, 599, 600, 610].contains(&f.sequence))
        .copied()
        .collect();
    assert_eq!(picks.len(), 4);
    let out = dir.path().join("kf");
    let names = write_keyframes(&path, Stream::Thermal, &picks, &out).unwrap();
    assert_eq!(names.len(), 4, "four distinct files: {names:?}");
    for f in &picks {
        let file = out.join(&names[&f.sequence]);
        assert!(file.is_file(), "{} written", file.display());
    }
}
