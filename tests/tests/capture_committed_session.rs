//! The committed session `tests/data/sim_lepton_rgb.mcap` (recorded by `s3tir-capture` from a
//! simulated Lepton 3.5 + RGB rig, with an FFC event and a dropped frame) replayed through
//! `info`, `replay` and `export`, with its counts asserted: the pattern by which a session
//! recorded on a real rig becomes a regression test (steps in capture/README.md).
//!
//! Proves: the file reads completely (not truncated) with the recorded frame, drop, FFC and
//! pair counts; replay reproduces every frame (digest) and every pair; export writes one
//! 16-bit thermal PNG and one RGB PNG per pair, named alike, with the recorded pixels.
//! Does NOT prove anything about frames newer code would record (it is a fixed file).
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;

use s3tir_tests::bin;
use serde_json::Value;

const SESSION: &str = "data/sim_lepton_rgb.mcap";

// Counts of the committed file (from `s3tir-capture info --json` when it was recorded).
const THERMAL_FRAMES: u64 = 52;
const THERMAL_DROPS: u64 = 1;
const FFC_FRAMES: u64 = 3;
const RGB_FRAMES: u64 = 55;
const PAIRS: u64 = 48;

fn session() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(SESSION)
}

fn run(args: &[&str]) -> Value {
    let out = Command::new(bin("s3tir-capture"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "s3tir-capture {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn committed_session_replays_through_info_replay_and_export() {
    let path = session();
    let p = path.to_str().unwrap();
    let info = run(&["info", "--json", p]);
    assert_eq!(info["truncated"], Value::Bool(false), "{info}");
    assert_eq!(
        info["streams"]["thermal"]["frames"], THERMAL_FRAMES,
        "{info}"
    );
    assert_eq!(info["streams"]["thermal"]["drops"], THERMAL_DROPS, "{info}");
    assert_eq!(
        info["streams"]["thermal"]["ffc_frames"], FFC_FRAMES,
        "{info}"
    );
    assert_eq!(info["streams"]["rgb"]["frames"], RGB_FRAMES, "{info}");
    assert_eq!(info["streams"]["rgb"]["drops"], 0, "{info}");
    assert_eq!(info["pairs"], PAIRS, "{info}");
    assert!(info["duration_s"].as_f64().unwrap() > 5.0, "{info}");

    let rep = run(&["replay", "--json", p]);
    assert_eq!(
        rep["frame_digest"], info["frame_digest"],
        "replay must reproduce every frame"
    );
    assert_eq!(rep["frames"], THERMAL_FRAMES + RGB_FRAMES);
    assert_eq!(rep["pairs"], PAIRS);
    assert_eq!(rep["pair_mismatches"], 0);

    let dir = tempfile::tempdir().unwrap();
    let summary = run(&["export", p, "--json", "--out", dir.path().to_str().unwrap()]);
    assert_eq!(summary["board_folder"]["pairs"], PAIRS, "{summary}");
    assert_eq!(
        summary["board_folder"]["dir"],
        dir.path().display().to_string(),
        "{summary}"
    );
    let names = |sub: &str| {
        let mut v: Vec<String> = std::fs::read_dir(dir.path().join(sub))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        v.sort();
        v
    };
    let thermal = names("thermal");
    assert_eq!(thermal.len() as u64, PAIRS, "one thermal PNG per pair");
    assert_eq!(thermal, names("rgb"), "paired by name");
    assert_eq!(thermal[0], "0000.png");
    // PNG IHDR: width, height (BE u32 at 16, 20), bit depth (24), colour type (25; 0 grey, 2 RGB).
    let ihdr = |path: PathBuf| {
        let b = std::fs::read(&path).unwrap();
        let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        (be(16), be(20), b[24], b[25])
    };
    assert_eq!(
        ihdr(dir.path().join("thermal/0000.png")),
        (160, 120, 16, 0),
        "thermal: 160x120 (telemetry rows not exported), 16-bit grey"
    );
    assert_eq!(
        ihdr(dir.path().join("rgb/0000.png")),
        (160, 120, 8, 2),
        "rgb: 8-bit RGB"
    );
}
