//! `s3tir-capture bench`: sustained recorder throughput on the rig's heaviest load, FLIR Boson
//! 640×512 Y16 at 60 Hz plus RGB 1920×1080 MJPEG at 30 Hz, through the live path (parse,
//! drop detection, pairing, MCAP chunking + LZ4, file writes).
//!
//! Buffers come from a ring of pre-generated synthetic frames (re-stamped with fresh sequence
//! numbers and times), so the figure measures the recorder, not the generator. The result is
//! reported as a ratio to real time: `realtime_ratio = 2.0` means the recorder keeps up with
//! twice the camera rates.
//!
//! The writer `fdatasync`s the file every [`SYNC_INTERVAL`](crate::session::SYNC_INTERVAL)
//! (the power-cut bound); the bench syncs once per second of camera time (the load runs
//! faster than real time, so each sync carries what it would in a recording). The CLI runs
//! the load twice in one process, with the syncs and without (the reference), and reports the
//! syncs' cost as the ratio of the two throughputs plus each sync's duration. Give `--out` on the rig's recording disk: a temp folder on
//! tmpfs makes syncs free.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use crate::backend::stamp::wall_now_ns;
use crate::backend::synth::{Script, SynthRig, ThermalSynth};
use crate::error::CaptureError;
use crate::frame::{RawFrame, StreamKind};
use crate::session::pairing::{DEFAULT_TOLERANCE_NS, PairingMode};
use crate::session::pipeline::Pipeline;
use crate::session::{SessionInfo, SessionWriter};

/// Result of one bench run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    pub simulated_s: f64,
    pub frames: u64,
    pub wall_s: f64,
    pub cpu_s: f64,
    pub frames_per_s: f64,
    /// Sustained frame rate over the cameras' combined rate (90 frames/s).
    pub realtime_ratio: f64,
    pub cpu_us_per_frame: f64,
    pub file_mb: f64,
    pub write_mb_per_s: f64,
    /// Whether the writer synced (false: the reference run).
    pub synced: bool,
    /// `fdatasync` calls and their mean and longest duration.
    pub syncs: u64,
    pub sync_ms_mean: f64,
    pub sync_ms_max: f64,
}

fn process_cpu_s() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(0.0)
}

/// Records `simulated_s` seconds of the Boson + 1080p load into `out` as fast as possible;
/// `sync = false` turns the writer's `fdatasync`s off (the reference run).
pub fn run(
    out: &Path,
    simulated_s: f64,
    rgb_size: (u32, u32),
    sync: bool,
) -> Result<BenchReport, CaptureError> {
    let mut rig = SynthRig::new(
        ThermalSynth::boson640(),
        Some((rgb_size.0, rgb_size.1, 30.0)),
        Script::default(),
        0,
    )?;
    // A ring of 8 thermal + 4 RGB distinct buffers.
    let mut ring: Vec<RawFrame> = Vec::new();
    while ring
        .iter()
        .filter(|f| f.stream == StreamKind::Thermal)
        .count()
        < 8
    {
        if let Some(b) = rig.next_buffer() {
            ring.push(b);
        }
    }
    let period_ns = [1e9 / 60.0, 1e9 / 30.0];
    let total = [
        (simulated_s * 60.0).round() as u64,
        (simulated_s * 30.0).round() as u64,
    ];
    let mut writer = SessionWriter::create(
        out,
        &SessionInfo {
            tool: "s3tir-capture bench".into(),
            thermal_device: "synthetic boson640".into(),
            ..SessionInfo::default()
        },
    )?;
    // The load runs faster than real time, so the wall-clock cadence would sync too rarely:
    // the bench syncs once per second of *camera* time instead (each sync then carries one
    // second of data, as in a recording).
    writer.set_sync_interval(None);
    let frames_per_sync =
        (crate::session::SYNC_INTERVAL.as_secs_f64() * 1e9 / period_ns[0]).round() as u64;
    let mut pipe = Pipeline::new(PairingMode::Nearest {
        tolerance_ns: DEFAULT_TOLERANCE_NS,
    });
    let thermal: Vec<&RawFrame> = ring
        .iter()
        .filter(|f| f.stream == StreamKind::Thermal)
        .collect();
    let rgb: Vec<&RawFrame> = ring
        .iter()
        .filter(|f| f.stream == StreamKind::Rgb)
        .collect();
    let cpu0 = process_cpu_s();
    let t0 = Instant::now();
    let mut next = [0u64; 2];
    let mut frames = 0u64;
    while next[0] < total[0] || next[1] < total[1] {
        let t = [
            next[0] as f64 * period_ns[0],
            next[1] as f64 * period_ns[1] + 2e6,
        ];
        let k = if next[1] >= total[1] || (next[0] < total[0] && t[0] <= t[1]) {
            0
        } else {
            1
        };
        let src = if k == 0 {
            thermal[next[k] as usize % thermal.len()]
        } else {
            rgb[next[k] as usize % rgb.len().max(1)]
        };
        let mut raw = src.clone();
        raw.sequence = next[k] as u32;
        raw.monotonic_ns = t[k] as u64;
        next[k] += 1;
        for r in pipe.push("bench", &raw, wall_now_ns())? {
            writer.write(&r)?;
        }
        frames += 1;
        if sync && k == 0 && next[0] % frames_per_sync.max(1) == 0 {
            writer.flush()?;
            writer.sync()?;
        }
    }
    for r in pipe.finish() {
        writer.write(&r)?;
    }
    let syncs_before_finish = writer.sync_stats();
    if sync {
        // The recording's closing sync.
        writer.set_sync_interval(Some(crate::session::SYNC_INTERVAL));
    }
    writer.finish()?;
    let wall_s = t0.elapsed().as_secs_f64();
    let cpu_s = process_cpu_s() - cpu0;
    let file_mb = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0) as f64 / 1e6;
    let fps = frames as f64 / wall_s;
    Ok(BenchReport {
        simulated_s,
        frames,
        wall_s,
        cpu_s,
        frames_per_s: fps,
        realtime_ratio: fps / 90.0,
        cpu_us_per_frame: cpu_s / frames as f64 * 1e6,
        file_mb,
        write_mb_per_s: file_mb / wall_s,
        synced: sync,
        // The periodic syncs (finish's final one is the same in any recording).
        syncs: syncs_before_finish.count,
        sync_ms_mean: if syncs_before_finish.count > 0 {
            syncs_before_finish.total.as_secs_f64() * 1e3 / syncs_before_finish.count as f64
        } else {
            0.0
        },
        sync_ms_max: syncs_before_finish.max.as_secs_f64() * 1e3,
    })
}
