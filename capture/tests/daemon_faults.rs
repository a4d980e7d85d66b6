//! Proves, in-process against the fake simulated rig (`FakeRig`, synthetic Lepton + RGB
//! buffers over the real simwire socket): the daemon records every delivered frame; scripted
//! FFC freezes are flagged and never paired; scripted drops are counted as drops; corrupt
//! MJPEG buffers are counted as rejected and not recorded; the daemon reconnects when the rig
//! vanishes and returns; a slow disk shows up as counted queue drops, not unbounded memory;
//! replay of the result reproduces every frame (same digest) and every pair; a device that
//! stalls (open, no error, no buffers) is reopened by the watchdog and counted, its restarted
//! sequence numbers do not lose the pairs after the reopen in `export`, and the outage is
//! counted as drops by time; the daemon reports a status event a second and a last
//! `Stopping` event saying whether its duration or its caller's stop flag ended it.
//! Does NOT run the binaries or the real `s3tir-firmware-sim` (tests/tests/capture_*.rs do)
//! and does not measure throughput (`s3tir-capture bench` does).
#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use s3tir_capture::CaptureError;
use s3tir_capture::backend::FrameSource;
use s3tir_capture::backend::sim_backend::{FakeRig, FakeRigConfig, SimSource};
use s3tir_capture::backend::synth::{Script, SynthRig, ThermalSynth};
use s3tir_capture::daemon::{self, Counters, DaemonConfig, SourceSpec};
use s3tir_capture::frame::RawFrame;
use s3tir_capture::session::SessionInfo;
use s3tir_capture::session::pairing::PairingMode;
use s3tir_capture::tools;

fn config(socket: &std::path::Path, out: &std::path::Path, secs: f64) -> DaemonConfig {
    let s = socket.to_owned();
    DaemonConfig {
        sources: vec![SourceSpec {
            name: "fake".into(),
            open: Box::new(move || {
                SimSource::connect(&s).map(|x| Box::new(x) as Box<dyn FrameSource>)
            }),
        }],
        out: out.to_owned(),
        info: SessionInfo {
            thermal_device: "fake".into(),
            pairing: serde_json::to_string(&PairingMode::Nearest {
                tolerance_ns: 60_000_000,
            })
            .unwrap(),
            ..SessionInfo::default()
        },
        pairing: PairingMode::Nearest {
            tolerance_ns: 60_000_000,
        },
        duration: Some(Duration::from_secs_f64(secs)),
        queue_frames: 64,
        calibration: None,
        slow_disk: None,
        stall_timeout: s3tir_capture::daemon::DEFAULT_STALL_TIMEOUT,
        ffc_poll: None,
        trigger_poll: None,
        rough_clock: None,
    }
}

#[test]
fn faults_are_counted_flagged_and_replay_matches() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let out = dir.path().join("s.mcap");
    // Lepton-shaped core and RGB both at 9 Hz (RGB 2 ms later): 20 + 20 buffers, then quiet.
    let script = Script {
        ffc_frames: vec![5, 6, 7],
        thermal_drops: vec![10],
        rgb_drops: vec![3],
        rgb_corrupt: vec![8],
    };
    let rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth {
                rate_hz: 9.0,
                ..ThermalSynth::lepton35()
            },
            rgb: Some((64, 48, 9.0)),
            script,
            unpaced: true,
            max_buffers: Some(40),
        },
    )
    .unwrap();
    let counters = Arc::new(Counters::default());
    let report = daemon::run(
        config(&sock, &out, 1.5),
        Arc::new(AtomicBool::new(false)),
        counters,
    )
    .unwrap();
    drop(rig);
    let produced_thermal = 20 - 1; // one scripted drop
    assert_eq!(
        report.thermal.frames, produced_thermal,
        "thermal frames recorded"
    );
    assert_eq!(report.thermal.ffc_frames, 3, "FFC-frozen frames flagged");
    assert_eq!(report.thermal.drops, 1, "thermal sequence gap counted");
    assert_eq!(report.rgb.rejected, 1, "corrupt MJPEG rejected");
    assert_eq!(
        report.rgb.frames,
        20 - 2,
        "rgb frames = produced − dropped − corrupt"
    );
    assert_eq!(
        report.rgb.drops, 2,
        "dropped + rejected buffers both leave sequence gaps"
    );
    let info = tools::info(&out).unwrap();
    assert!(
        !info.truncated,
        "cleanly finished session: {:?}",
        info.truncation_reason
    );
    assert_eq!(info.streams["thermal"].frames, produced_thermal);
    assert_eq!(info.streams["thermal"].ffc_frames, 3);
    assert_eq!(
        info.streams["rgb"].rejected, 1,
        "rejections recorded in status"
    );
    assert_eq!(info.pairs, report.pairs);
    // Never paired: FFC-frozen thermal sequences 5, 6, 7.
    let mut paired_frozen = 0;
    s3tir_capture::session::read_session(&out, |item| {
        if let s3tir_capture::session::SessionItem::Pair(p) = item
            && (5..=7).contains(&p.thermal_sequence)
        {
            paired_frozen += 1;
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(paired_frozen, 0, "frozen frames must never be paired");
    let replayed = tools::replay(&out, None, false, None, |_| {}).unwrap();
    assert_eq!(
        replayed.frame_digest, info.frame_digest,
        "replay reproduces every frame"
    );
    assert_eq!(replayed.pair_mismatches, 0);
    assert_eq!(replayed.pairs, info.pairs);
}

#[test]
fn daemon_reconnects_when_the_rig_vanishes_and_returns() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let out = dir.path().join("s.mcap");
    let rig = Arc::new(
        FakeRig::start(
            &sock,
            FakeRigConfig {
                thermal: ThermalSynth::lepton35(),
                rgb: None,
                script: Script::default(),
                unpaced: false,
                max_buffers: None,
            },
        )
        .unwrap(),
    );
    let r2 = rig.clone();
    let toggler = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(700));
        r2.set_vanished(true);
        std::thread::sleep(Duration::from_millis(700));
        r2.set_vanished(false);
    });
    let counters = Arc::new(Counters::default());
    let report = daemon::run(
        config(&sock, &out, 3.0),
        Arc::new(AtomicBool::new(false)),
        counters,
    )
    .unwrap();
    toggler.join().unwrap();
    assert!(
        report.status.reconnects >= 1,
        "reconnects: {}",
        report.status.reconnects
    );
    // 3 s at 8.7 Hz minus ~0.7 s unplugged ≈ 20 frames; the gap shows as drops.
    assert!(
        (12..=27).contains(&report.thermal.frames),
        "frames around the outage: {}",
        report.thermal.frames
    );
    assert!(
        report.thermal.drops >= 3,
        "frames missed while unplugged are drops: {}",
        report.thermal.drops
    );
    let info = tools::info(&out).unwrap();
    assert_eq!(info.reconnects, report.status.reconnects);
}

#[test]
fn slow_disk_becomes_counted_queue_drops() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let out = dir.path().join("s.mcap");
    let _rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth::lepton35(),
            rgb: None,
            script: Script::default(),
            unpaced: true,
            max_buffers: Some(400),
        },
    )
    .unwrap();
    let mut cfg = config(&sock, &out, 1.5);
    cfg.queue_frames = 4;
    cfg.slow_disk = Some(Duration::from_millis(20));
    let counters = Arc::new(Counters::default());
    let stop = Arc::new(AtomicBool::new(false));
    let report = daemon::run(cfg, stop.clone(), counters.clone()).unwrap();
    let q = report.status.queue_drops_thermal;
    assert!(
        q > 100,
        "a writer at 50 frames/s against 400 instant frames drops most: {q}"
    );
    assert_eq!(
        report.thermal.frames,
        counters.frames[0].load(Ordering::Relaxed),
        "live counters agree with the pipeline"
    );
    assert!(
        report.thermal.frames <= 100,
        "recorded {}",
        report.thermal.frames
    );
    let info = tools::info(&out).unwrap();
    assert_eq!(
        info.streams["thermal"].queue_drops, q,
        "queue drops in the session"
    );
    let gaps = info.streams["thermal"].drops;
    // Drops after the last recorded frame leave no gap: when the reader takes all 400 instant
    // frames before the writer frees a slot, only the queue's first frames are recorded and
    // every drop is trailing (seen under load: 5 recorded, 395 dropped, 0 gaps).
    let all_trailing = report.thermal.frames <= 4 + 2;
    assert!(
        gaps <= q && (gaps > 0 || all_trailing),
        "queue drops show as sequence gaps (except trailing ones): gaps {gaps}, queue drops {q}, recorded {}",
        report.thermal.frames
    );
}

#[test]
fn a_full_disk_is_an_error_naming_the_file_not_a_hang() {
    if !std::path::Path::new("/dev/full").exists() {
        s3tir_capture::skip::skip("dev-full", "no /dev/full on this machine");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let _rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth::lepton35(),
            rgb: None,
            script: Script::default(),
            unpaced: false,
            max_buffers: None,
        },
    )
    .unwrap();
    let mut cfg = config(&sock, std::path::Path::new("/dev/full"), 30.0);
    cfg.duration = None; // only the error may end it
    let t0 = std::time::Instant::now();
    let err = daemon::run(
        cfg,
        Arc::new(AtomicBool::new(false)),
        Arc::new(Counters::default()),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("/dev/full"), "error names the file: {err}");
    assert!(t0.elapsed() < Duration::from_secs(10), "fails promptly");
}

/// A camera that delivers `before` buffers, then stalls (stays open, times out forever); once
/// reopened it restarts its sequence numbers at 0 (as a re-enumerated V4L2 device does) and
/// its stamps jump by the outage, then it delivers `after` buffers and goes quiet.
struct StallingCamera {
    rig: SynthRig,
    open_index: usize,
    delivered: usize,
    before: usize,
    after: usize,
}

const OUTAGE_NS: u64 = 1_000_000_000;

impl FrameSource for StallingCamera {
    fn name(&self) -> &str {
        "stalling"
    }
    fn next_frame(&mut self, timeout: Duration) -> Result<Option<RawFrame>, CaptureError> {
        let limit = if self.open_index == 0 {
            self.before
        } else {
            self.after
        };
        if self.delivered >= limit {
            std::thread::sleep(timeout);
            return Ok(None);
        }
        let mut raw = self.rig.next_buffer().unwrap();
        self.delivered += 1;
        if self.open_index > 0 {
            raw.monotonic_ns += OUTAGE_NS;
        }
        std::thread::sleep(Duration::from_micros(300));
        Ok(Some(raw))
    }
}

#[test]
fn a_stalled_camera_is_reopened_and_its_restarted_sequences_keep_their_pairs() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("stall.mcap");
    let opens = Arc::new(AtomicUsize::new(0));
    // Boson-rate thermal (60 Hz) + 30 Hz RGB, 2 ms apart: 900 buffers (10 s of camera time,
    // more than the 512-frame windows) before the stall, 150 after.
    let (before, after) = (900, 150);
    let o = opens.clone();
    let make = move || -> Result<Box<dyn FrameSource>, CaptureError> {
        let k = o.fetch_add(1, Ordering::SeqCst);
        let thermal = ThermalSynth {
            width: 64,
            height: 48,
            ..ThermalSynth::boson640()
        };
        let mut rig = SynthRig::new(thermal, Some((64, 48, 30.0)), Script::default(), 0).unwrap();
        if k > 0 {
            // The second open continues the scene's clock where the first left it (plus the
            // outage), but numbers its frames from 0 again.
            for _ in 0..before {
                rig.next_buffer();
            }
            rig.restart_sequences();
        }
        Ok(Box::new(StallingCamera {
            rig,
            open_index: k,
            delivered: 0,
            before,
            after,
        }))
    };
    let mut cfg = config(Path::new("/nonexistent"), &out, 0.0);
    cfg.sources = vec![SourceSpec {
        name: "stalling".into(),
        open: Box::new(make),
    }];
    cfg.duration = None;
    cfg.stall_timeout = Duration::from_millis(400);
    let stop = Arc::new(AtomicBool::new(false));
    let counters = Arc::new(Counters::default());
    // Stop once the second open has delivered everything.
    let watcher = {
        let stop = stop.clone();
        let counters = counters.clone();
        let opens = opens.clone();
        std::thread::spawn(move || {
            let t0 = std::time::Instant::now();
            while t0.elapsed() < Duration::from_secs(30) {
                let n = counters.frames[0].load(Ordering::Relaxed)
                    + counters.frames[1].load(Ordering::Relaxed);
                if opens.load(Ordering::SeqCst) >= 2 && n >= (before + after) as u64 {
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            std::thread::sleep(Duration::from_millis(100));
            stop.store(true, Ordering::SeqCst);
        })
    };
    let report = daemon::run(cfg, stop, counters).unwrap();
    watcher.join().unwrap();
    assert_eq!(report.status.stalls, 1, "one stall, counted");
    assert_eq!(report.status.reconnects, 1, "reopened once");
    assert_eq!(
        (report.thermal.frames + report.rgb.frames) as usize,
        before + after,
        "every delivered buffer recorded"
    );
    // 1 s outage: ~60 thermal and ~30 RGB frame times, minus the one frame that arrives.
    assert!(
        (55..=62).contains(&report.thermal.drops),
        "thermal drops across the outage counted by time: {}",
        report.thermal.drops
    );
    assert!(
        (26..=32).contains(&report.rgb.drops),
        "RGB drops across the outage counted by time: {}",
        report.rgb.drops
    );
    let info = tools::info(&out).unwrap();
    assert_eq!(
        info.stalls, 1,
        "the session's status records carry the stall"
    );
    // Export finds the frames of every recorded pair, including those after the restart
    // (a window keyed by sequence evicted exactly those).
    let pairs_after: u64 = {
        let mut n = 0;
        let mut restarted = false;
        let mut last = 0u32;
        s3tir_capture::session::read_session(&out, |item| {
            match item {
                s3tir_capture::session::SessionItem::Frame(f)
                    if f.raw.stream == s3tir_capture::frame::StreamKind::Thermal =>
                {
                    restarted |= f.raw.sequence < last;
                    last = f.raw.sequence;
                }
                s3tir_capture::session::SessionItem::Pair(_) if restarted => n += 1,
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        n
    };
    assert!(pairs_after >= 40, "pairs after the restart: {pairs_after}");
    let exported = tools::export(&out, &dir.path().join("export")).unwrap();
    println!(
        "stall test: {} stall, {} reconnect, drops thermal {} rgb {}, {} pairs ({pairs_after} after the restart), {exported} exported",
        report.status.stalls,
        report.status.reconnects,
        report.thermal.drops,
        report.rgb.drops,
        info.pairs
    );
    assert_eq!(
        exported, info.pairs,
        "export writes every recorded pair ({pairs_after} after the restart)"
    );
}

#[test]
fn the_daemon_reports_status_events_and_stops_on_its_callers_flag() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let _rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth {
                rate_hz: 9.0,
                ..ThermalSynth::lepton35()
            },
            rgb: None,
            script: Script::default(),
            unpaced: false,
            max_buffers: None,
        },
    )
    .unwrap();
    // The duration ends the first recording; the caller's flag the second (no duration).
    for (secs, why) in [
        (Some(1.5), daemon::StopReason::Duration),
        (None, daemon::StopReason::Requested),
    ] {
        let out = dir.path().join(format!("{why:?}.mcap"));
        let mut cfg = config(&sock, &out, 1.0);
        cfg.duration = secs.map(Duration::from_secs_f64);
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let stopper = std::thread::spawn(move || {
            if secs.is_none() {
                std::thread::sleep(Duration::from_millis(1500));
                flag.store(true, Ordering::Relaxed);
            }
        });
        let mut events = Vec::new();
        let report =
            daemon::run_with_events(cfg, stop, Arc::new(Counters::default()), |e| events.push(e))
                .unwrap();
        stopper.join().unwrap();
        let statuses = events
            .iter()
            .filter(|e| matches!(e, daemon::DaemonEvent::Status { .. }))
            .count();
        assert!(statuses >= 1, "a status event a second: {events:?}");
        assert_eq!(
            events.last(),
            Some(&daemon::DaemonEvent::Stopping { why }),
            "the last event says why the recording ends"
        );
        assert!(report.thermal.frames > 0, "{report:?}");
    }
}
