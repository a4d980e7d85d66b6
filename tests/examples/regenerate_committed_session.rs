//! Regenerates the committed session `tests/data/sim_lepton_rgb.mcap` that
//! `tests/capture_committed_session.rs` replays: 6 s of the simulated Lepton 3.5 + RGB rig with
//! an FFC event (frames 20–22) and a dropped thermal frame (40), recorded by the real
//! `s3tir-capture` binary.
//!
//! ```sh
//! cargo build --workspace --bins
//! cargo run -p s3tir-tests --example regenerate_committed_session
//! s3tir-capture info --json tests/data/sim_lepton_rgb.mcap   # then update the test's constants
//! ```
//!
//! The recorder never writes over a file: the old session is moved aside to `*.mcap.old` first
//! and put back if the recording fails.

use std::path::PathBuf;
use std::process::{Command, ExitCode, Stdio};

use s3tir_capture::backend::sim_backend::{FakeRig, FakeRigConfig};
use s3tir_capture::backend::synth::{Script, ThermalSynth};
use s3tir_tests::bin;

fn main() -> ExitCode {
    let session = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/sim_lepton_rgb.mcap");
    let old = session.with_extension("mcap.old");
    match regenerate(&session, &old) {
        Ok(()) => {
            let _ = std::fs::remove_file(&old);
            println!("wrote {}", session.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("regenerating {} failed: {e}", session.display());
            if old.exists() {
                let _ = std::fs::remove_file(&session);
                let _ = std::fs::rename(&old, &session);
            }
            ExitCode::FAILURE
        }
    }
}

fn regenerate(session: &std::path::Path, old: &std::path::Path) -> Result<(), String> {
    let capture = bin("s3tir-capture");
    if !capture.exists() {
        return Err(format!(
            "{} not built: run `cargo build --workspace --bins` first",
            capture.display()
        ));
    }
    if session.exists() {
        std::fs::rename(session, old).map_err(|e| format!("move the old session aside: {e}"))?;
    }
    let dir = tempfile::tempdir().map_err(|e| format!("temporary folder: {e}"))?;
    let sock = dir.path().join("rig.sock");
    let _rig = FakeRig::start(
        &sock,
        FakeRigConfig {
            thermal: ThermalSynth::lepton35(),
            rgb: Some((160, 120, 9.0)),
            script: Script {
                ffc_frames: vec![20, 21, 22],
                thermal_drops: vec![40],
                ..Script::default()
            },
            unpaced: false,
            max_buffers: None,
        },
    )
    .map_err(|e| format!("start the simulated rig: {}", s3tir_capture::Chain(&e)))?;
    let status = Command::new(&capture)
        .args([
            "--device",
            "sim:lepton35",
            "--rgb",
            "sim",
            "--duration-s",
            "6",
        ])
        .args(["--pair-tolerance-ms", "60"])
        .arg("--sim-socket")
        .arg(&sock)
        .arg("--out")
        .arg(session)
        .stdin(Stdio::null())
        .status()
        .map_err(|e| format!("run {}: {e}", capture.display()))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("s3tir-capture exited with {status}"))
    }
}
