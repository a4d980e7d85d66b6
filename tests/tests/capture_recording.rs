//! End-to-end tests of the `s3tir-capture` binary recording from a simulated rig.
//!
//! Proves: a 10 s Boson-profile (640×512 Y16 @ 60 Hz) + RGB (MJPEG @ 30 Hz) recording has
//! no unexplained drops (every sequence gap is a counted queue drop), `info --json` reports
//! the expected counts with the documented keys, and `replay` reproduces every frame
//! byte-for-byte (equal frame digests, and a re-recorded session with the same digest and
//! pairs); a recorder killed with SIGKILL leaves a file that reads back to its last flushed
//! chunk (≤ ~1 s lost) and `info` says it was truncated; `--device sim` with no rig running
//! starts the `s3tir-firmware-sim` installed beside it, stops it at exit, and `--json` prints
//! a summary that agrees with the file.
//!
//! The rig is the in-process `FakeRig` (synthetic buffers over the real simwire socket, a
//! source fully under the test's control); `capture_sim_rig.rs` records the same 10 s from the
//! real `s3tir-firmware-sim run`. It does NOT test physical plausibility of frames, nor real
//! V4L2 devices.
#![allow(clippy::unwrap_used)]

use std::process::{Command, Stdio};
use std::time::Duration;

use s3tir_capture::backend::sim_backend::{FakeRig, FakeRigConfig};
use s3tir_capture::backend::synth::{Script, ThermalSynth};
use s3tir_tests::{bin, capture_info_json as info_json, capture_replay_json, json_u64 as u};
use serde_json::Value;

#[test]
fn ten_second_boson_rgb_recording_is_complete_and_replays_byte_exact() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let out = dir.path().join("ten.mcap");
    let rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth::boson640(),
            rgb: Some((640, 480, 30.0)),
            script: Script::default(),
            unpaced: false,
            max_buffers: None,
        },
    )
    .unwrap();
    let status = Command::new(bin("s3tir-capture"))
        .args([
            "--device",
            "sim:boson640",
            "--rgb",
            "sim",
            "--duration-s",
            "10",
        ])
        .arg("--sim-socket")
        .arg(&sock)
        .arg("--out")
        .arg(&out)
        .stdin(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success(), "recording exited {status:?}");
    drop(rig);

    let info = info_json(&out);
    assert_eq!(info["truncated"], Value::Bool(false), "clean stop: {info}");
    let thermal = u(&info, &["streams", "thermal", "frames"]);
    let rgb = u(&info, &["streams", "rgb", "frames"]);
    // 10 s at 60 / 30 Hz, less the ~0.1 s the recorder takes to connect.
    assert!(
        (560..=605).contains(&thermal),
        "thermal frames {thermal}, want ≈600"
    );
    assert!((280..=303).contains(&rgb), "rgb frames {rgb}, want ≈300");
    for s in ["thermal", "rgb"] {
        let drops = u(&info, &["streams", s, "drops"]);
        let queue = u(&info, &["streams", s, "queue_drops"]);
        assert_eq!(
            drops, queue,
            "{s}: {drops} frames missing but only {queue} explained by the recorder's queue"
        );
        assert_eq!(
            u(&info, &["streams", s, "ffc_frames"]),
            0,
            "{s}: no FFC scripted"
        );
    }
    let pairs = u(&info, &["pairs"]);
    assert!(
        pairs + 2 >= rgb,
        "every RGB frame has a thermal frame 2 ms away: {pairs} pairs, {rgb} rgb"
    );
    let duration = info["duration_s"].as_f64().unwrap();
    assert!((9.3..=10.1).contains(&duration), "duration {duration}");

    // Replay: same frames (digest), same pairs, and a re-recorded session identical in content.
    let replayed = dir.path().join("replayed.mcap");
    let rep = capture_replay_json(&out, Some(&replayed));
    assert_eq!(
        rep["frame_digest"], info["frame_digest"],
        "replayed frames differ"
    );
    assert_eq!(u(&rep, &["frames"]), thermal + rgb);
    assert_eq!(u(&rep, &["pair_mismatches"]), 0);
    let info2 = info_json(&replayed);
    assert_eq!(info2["frame_digest"], info["frame_digest"]);
    assert_eq!(info2["pairs"], info["pairs"]);
    assert_eq!(info2["streams"], info["streams"]);
}

#[test]
fn sigkill_mid_recording_loses_at_most_about_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("rig.sock");
    let out = dir.path().join("killed.mcap");
    let rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth::boson640(),
            rgb: None,
            script: Script::default(),
            unpaced: false,
            max_buffers: None,
        },
    )
    .unwrap();
    let mut child = Command::new(bin("s3tir-capture"))
        .args(["--device", "sim:boson640"])
        .arg("--sim-socket")
        .arg(&sock)
        .arg("--out")
        .arg(&out)
        .stdin(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(3500));
    let sent = rig.sent.load(std::sync::atomic::Ordering::Relaxed);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    drop(rig);
    let info = info_json(&out);
    assert_eq!(
        info["truncated"],
        Value::Bool(true),
        "a killed recording is truncated: {info}"
    );
    let frames = u(&info, &["streams", "thermal", "frames"]);
    assert!(frames > 0, "flushed chunks must be readable");
    // `sent` was read just before the kill; at 60 Hz one second is 60 frames.
    let lost = sent.saturating_sub(frames);
    eprintln!("SIGKILL after 3.5 s: rig sent {sent} frames, {frames} readable, {lost} lost");
    assert!(
        lost <= 72,
        "lost {lost} frames (sent {sent}, readable {frames}): more than ~1.2 s at 60 Hz"
    );
}

#[test]
fn sim_device_without_a_rig_uses_the_installed_simulator_and_json_reports_the_recording() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("nobody.sock");
    let out = dir.path().join("s.mcap");
    let o = Command::new(bin("s3tir-capture"))
        .args(["--device", "sim:lepton35", "--duration-s", "2", "--json"])
        .arg("--sim-socket")
        .arg(&sock)
        .arg("--out")
        .arg(&out)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "recording from the installed simulator failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        std::os::unix::net::UnixStream::connect(&sock).is_err(),
        "the simulator started by s3tir-capture must be stopped at exit"
    );
    // --json: stdout is one object describing what was recorded, agreeing with the file.
    let summary: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!(
            "record --json stdout is not one JSON object ({e}): {}",
            String::from_utf8_lossy(&o.stdout)
        )
    });
    assert_eq!(summary["session"], out.display().to_string(), "{summary}");
    let info = info_json(&out);
    let frames = u(&info, &["streams", "thermal", "frames"]);
    assert!(frames > 0, "{info}");
    assert_eq!(
        summary["thermal"]["frames"].as_u64(),
        Some(frames),
        "the summary counts the frames the file holds: {summary}"
    );
    assert!(
        summary["bytes_written"].as_u64().is_some_and(|b| b > 0),
        "{summary}"
    );
}
