//! Calibration from a recorded session (`.mcap`) instead of a folder.
//!
//! Proves: a session written by the capture crate's `SessionWriter` (16-bit thermal frames,
//! YUYV RGB frames, `/pairs` records) of a synthetic board set calibrates through
//! `calibrate_session` to the same views, pairs and (within 0.05 % / 0.05 px) the same thermal
//! intrinsics as the folder the frames came from; a pair whose thermal frame is FFC-frozen is
//! skipped and listed with the reason; a pair closer than `min_interval_s` to the previous one
//! is skipped and counted in a warning; the CLI refuses a session without `--board` with a
//! message naming the flag, and accepts it with `--board` (and `--session-interval-s 2.5`
//! takes 3 of the 7 pairs recorded 1 s apart).
//! Does not prove: sessions recorded from real devices (telemetry-derived FFC states, MJPEG
//! artefacts) or truncated sessions (the capture crate's reader tests cover truncation).
//! Takes ~60 s of CPU in the dev profile (two calibrations of 7 small synthetic pairs and one
//! of 3); the committed-session check takes well under a second.
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::Command;

use s3tir_calib::detect::session::SessionOptions;
use s3tir_calib::solve::pipeline::{PipelineOptions, calibrate_folder, calibrate_session};
use s3tir_calib::synth::{self, SynthOptions};
use s3tir_capture::frame::{
    CapturedFrame, FfcState, FrameTime, RgbFrame, RgbPayload, ThermalFrame, ThermalUnits,
};
use s3tir_capture::session::{PairRecord, SessionInfo, SessionRecord, SessionWriter};

const VIEWS: usize = 7;

/// BT.601 limited-range RGB → YUYV 4:2:2 (the inverse of the capture crate's decoder).
fn yuyv_from_rgb(img: &image::RgbImage) -> Vec<u8> {
    let mut out = Vec::with_capacity(img.as_raw().len() / 3 * 2);
    for row in img.rows() {
        let px: Vec<[f32; 3]> = row.map(|p| p.0.map(f32::from)).collect::<Vec<_>>();
        for pair in px.chunks(2) {
            let y = |c: [f32; 3]| 16.0 + 0.257 * c[0] + 0.504 * c[1] + 0.098 * c[2];
            let avg = [0, 1, 2].map(|k| (pair[0][k] + pair[pair.len() - 1][k]) * 0.5);
            let u = 128.0 - 0.148 * avg[0] - 0.291 * avg[1] + 0.439 * avg[2];
            let v = 128.0 + 0.439 * avg[0] - 0.368 * avg[1] - 0.071 * avg[2];
            let b = |x: f32| x.round().clamp(0.0, 255.0) as u8;
            out.extend_from_slice(&[b(y(pair[0])), b(u), b(y(pair[pair.len() - 1])), b(v)]);
        }
    }
    out
}

fn thermal_frame(path: &Path, sequence: u32, t_ns: u64, ffc: FfcState) -> CapturedFrame {
    let img = image::open(path).unwrap().to_luma16();
    CapturedFrame::Thermal(ThermalFrame {
        width: img.width(),
        height: img.height(),
        pixels: img.into_raw(),
        units: ThermalUnits::CentiKelvin,
        time: FrameTime {
            sequence,
            monotonic_ns: t_ns,
            wall_unix_ns: 1_700_000_000_000_000_000 + t_ns,
        },
        ffc,
        telemetry_words: Vec::new(),
        telemetry: None,
    })
}

fn rgb_frame(path: &Path, sequence: u32, t_ns: u64) -> CapturedFrame {
    let img = image::open(path).unwrap().to_rgb8();
    CapturedFrame::Rgb(RgbFrame {
        width: img.width(),
        height: img.height(),
        payload: RgbPayload::Yuyv(yuyv_from_rgb(&img)),
        time: FrameTime {
            sequence,
            monotonic_ns: t_ns + 2_000_000,
            wall_unix_ns: 1_700_000_000_000_000_000 + t_ns + 2_000_000,
        },
    })
}

fn pair(t: &CapturedFrame, r: &CapturedFrame) -> SessionRecord {
    let (CapturedFrame::Thermal(t), CapturedFrame::Rgb(r)) = (t, r) else {
        panic!("pair(thermal, rgb)");
    };
    SessionRecord::Pair(PairRecord {
        thermal_sequence: t.time.sequence,
        rgb_sequence: r.time.sequence,
        thermal_monotonic_ns: t.time.monotonic_ns,
        rgb_monotonic_ns: r.time.monotonic_ns,
        sync_error_ns: t.time.monotonic_ns as i64 - r.time.monotonic_ns as i64,
    })
}

/// Writes the folder's pairs as a session, one per second, plus an FFC-frozen pair after
/// view 3 and a near-duplicate pair 0.1 s after view 6.
fn write_session(dir: &Path, out: &Path) {
    let mut w = SessionWriter::create(
        out,
        &SessionInfo {
            tool: "session_input test".into(),
            thermal_device: "synthetic".into(),
            rgb_device: Some("synthetic".into()),
            thermal_serial: None,
            pairing: "nearest".into(),
            notes: String::new(),
        },
    )
    .unwrap();
    let mut seq = 100u32;
    for k in 0..VIEWS {
        let t_ns = (k as u64 + 1) * 1_000_000_000;
        let tp = dir.join(format!("thermal/thermal_{k:04}.png"));
        let rp = dir.join(format!("rgb/rgb_{k:04}.png"));
        let t = thermal_frame(&tp, seq, t_ns, FfcState::Idle);
        let r = rgb_frame(&rp, seq + 1000, t_ns);
        for frame in [&t, &r] {
            w.write(&SessionRecord::Frame {
                frame: frame.clone(),
                ffc_hint: FfcState::Idle,
            })
            .unwrap();
        }
        w.write(&pair(&t, &r)).unwrap();
        seq += 1;
        let extra_ns = match k {
            3 => Some((t_ns + 600_000_000, FfcState::InProgress)),
            6 => Some((t_ns + 100_000_000, FfcState::Idle)),
            _ => None,
        };
        if let Some((e_ns, ffc)) = extra_ns {
            let t = thermal_frame(&tp, seq, e_ns, ffc);
            let r = rgb_frame(&rp, seq + 1000, e_ns);
            for frame in [&t, &r] {
                w.write(&SessionRecord::Frame {
                    frame: frame.clone(),
                    ffc_hint: ffc,
                })
                .unwrap();
            }
            w.write(&pair(&t, &r)).unwrap();
            seq += 1;
        }
    }
    w.finish().unwrap();
}

#[test]
fn a_recorded_session_calibrates_like_its_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("set");
    let rig = synth::rig(synth::lepton(), synth::rgb_360p());
    let opts = SynthOptions::new(synth::default_board(), VIEWS, 41);
    let truth = synth::write_board_folder(&dir, &rig, &opts).unwrap();
    let session = tmp.path().join("board.mcap");
    write_session(&dir, &session);

    let pipeline = PipelineOptions::default();
    let folder = calibrate_folder(&dir, &pipeline).unwrap();
    let cal = calibrate_session(
        &session,
        &dir.join("board.toml"),
        &SessionOptions::default(),
        &pipeline,
    )
    .unwrap();

    let (ft, st) = (
        folder.cameras[0].as_ref().unwrap(),
        cal.cameras[0].as_ref().unwrap(),
    );
    assert_eq!(
        (st.images, st.views_found),
        (VIEWS, ft.views_found),
        "session thermal images/views found vs the folder's ({} images, {} found)",
        ft.images,
        ft.views_found
    );
    assert_eq!(
        cal.pairs_used, folder.pairs_used,
        "pairs used: session {} vs folder {}",
        cal.pairs_used, folder.pairs_used
    );
    let (a, b) = (st.model.intrinsics, ft.model.intrinsics);
    assert!(
        ((a.fx - b.fx) / b.fx).abs() < 5e-4
            && (a.cx - b.cx).abs() < 0.05
            && (a.cy - b.cy).abs() < 0.05,
        "session thermal fx/cx/cy {:.3}/{:.3}/{:.3} vs folder {:.3}/{:.3}/{:.3}",
        a.fx,
        a.cx,
        a.cy,
        b.fx,
        b.cx,
        b.cy
    );
    let true_fx = truth.rig.thermal.intrinsics.fx;
    assert!(
        ((a.fx - true_fx) / true_fx).abs() < 0.01,
        "session thermal fx {:.3} vs truth {true_fx:.3}",
        a.fx
    );
    assert!(
        cal.problems.iter().any(|p| p.reason.contains("FFC-frozen")
            && p.path.to_string_lossy().contains("board.mcap#thermal/")),
        "the FFC-frozen pair must be listed by frame; problems: {:#?}",
        cal.problems
    );
    assert!(
        cal.warnings.iter().any(|w| w.contains(&format!(
            "{VIEWS} of {} recorded pairs used, 1 skipped",
            VIEWS + 2
        ))),
        "the near-duplicate pair must be counted in a warning; warnings: {:#?}",
        cal.warnings
    );

    // The CLI: refused without --board, accepted with it.
    let exe = env!("CARGO_BIN_EXE_s3tir-calib");
    let out = Command::new(exe)
        .arg(&session)
        .arg("--out")
        .arg(tmp.path().join("cli/calibration.yaml"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("--board"),
        "without --board the CLI must fail naming the flag; status {}, stderr:\n{stderr}",
        out.status
    );
    let summary = tmp.path().join("cli/summary.json");
    let out = Command::new(exe)
        .arg(&session)
        .arg("--board")
        .arg(dir.join("board.toml"))
        .arg("--out")
        .arg(tmp.path().join("cli/calibration.yaml"))
        .arg("--summary-json")
        .arg(&summary)
        .arg("--session-interval-s")
        .arg("2.5")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "with --board the CLI must calibrate; status {}, stderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    // Pairs 1 s apart taken at least 2.5 s apart: those at 1, 4 and 7 s.
    assert_eq!(
        json["pairs_used"].as_u64(),
        Some(3),
        "CLI with --session-interval-s 2.5 should use 3 of the 7 pairs: {json}"
    );
}

/// The committed session recorded by `s3tir-capture` from the simulated rig (a board at a fixed
/// pose; `tests/data/sim_lepton_rgb.mcap`, 48 pairs, counts asserted in
/// `tests/tests/capture_committed_session.rs`) reads through the same path: every recorded
/// pair becomes a view (interval 0) or is listed as skipped, and its frames decode at their
/// recorded sizes. Calibrating it is not meaningful (one board pose), so it is not attempted.
#[test]
fn the_committed_capture_session_reads_as_views() {
    let session = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/sim_lepton_rgb.mcap");
    let views = s3tir_calib::detect::session::read_views(
        &session,
        &SessionOptions {
            min_interval_s: 0.0,
            ..SessionOptions::default()
        },
    )
    .unwrap();
    let ffc_skipped = views
        .problems
        .iter()
        .filter(|p| p.reason.contains("FFC-frozen"))
        .count();
    assert_eq!(
        views.views.len() + ffc_skipped,
        48,
        "48 recorded pairs: {} views + {ffc_skipped} FFC-skipped; problems {:#?}",
        views.views.len(),
        views.problems
    );
    assert!(
        views.problems.len() == ffc_skipped,
        "no other problems expected: {:#?}",
        views.problems
    );
    let first = &views.views[0];
    let [Some(t), Some(r)] = &first.files else {
        panic!("a pair has both frames: {first:?}");
    };
    let thermal = views
        .images
        .load(t, s3tir_calib::detect::board::Camera::Thermal)
        .unwrap();
    let rgb = views
        .images
        .load(r, s3tir_calib::detect::board::Camera::Rgb)
        .unwrap();
    assert_eq!(
        (thermal.width_px, thermal.height_px),
        (160, 120),
        "Lepton frame size"
    );
    let (lo, hi) = rgb
        .values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    assert!(
        rgb.values.len() == (rgb.width_px * rgb.height_px) as usize && hi - lo > 10.0,
        "RGB frame decodes to an image with content: {}x{}, values {lo}..{hi}",
        rgb.width_px,
        rgb.height_px
    );
}
