//! `s3tir-capture bench`: the recorder's sustained throughput on synthetic Boson + 1080p RGB
//! buffers, and what the writer's fdatasync costs against a run without syncs.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;

use super::positive_seconds;

/// Options of `s3tir-capture bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Seconds of camera time to record.
    #[arg(long, default_value_t = 10.0, value_parser = positive_seconds)]
    seconds: f64,
    /// Where to write the bench session (must not exist; deleted afterwards). Put it on the
    /// rig's recording disk: the fdatasync cost depends on it (a tmpfs makes it free).
    #[arg(long)]
    out: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

/// Runs `bench`.
pub fn run(a: &BenchArgs) -> Result<()> {
    let (seconds, json) = (a.seconds, a.json);
    let dir = tempfile_dir()?;
    let path = a.out.clone().unwrap_or_else(|| dir.join("bench.mcap"));
    // The reference run (no fdatasync) beside the measured one, in the same folder and process.
    let mut reference_path = path.as_os_str().to_owned();
    reference_path.push(".reference");
    let reference_path = PathBuf::from(reference_path);
    for p in [&path, &reference_path] {
        if p.exists() {
            bail!(
                "{} exists: the bench writes and then deletes its own files there; give a new --out",
                p.display()
            );
        }
    }
    let reference = s3tir_capture::bench::run(&reference_path, seconds, (1920, 1080), false);
    let _ = std::fs::remove_file(&reference_path);
    let r = s3tir_capture::bench::run(&path, seconds, (1920, 1080), true);
    let _ = std::fs::remove_file(&path);
    let _ = std::fs::remove_dir(&dir);
    let (reference, r) = (reference?, r?);
    let sync_cost = 1.0 - r.frames_per_s / reference.frames_per_s;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "synced": r,
                "reference_without_sync": reference,
                "sync_cost": sync_cost,
            }))?
        );
    } else {
        println!(
            "recorded {:.1} s of Boson 640x512 Y16@60 + RGB 1920x1080 MJPEG@30 ({} frames) in {:.2} s wall, {:.2} s CPU",
            r.simulated_s, r.frames, r.wall_s, r.cpu_s
        );
        println!(
            "  {:.1} frames/s sustained = {:.2}x real time; {:.0} us CPU per frame; {:.1} MB at {:.1} MB/s",
            r.frames_per_s, r.realtime_ratio, r.cpu_us_per_frame, r.file_mb, r.write_mb_per_s
        );
        println!(
            "  fdatasync every {:.1} s: {} syncs, mean {:.1} ms, max {:.1} ms; without them {:.2}x real time \
             (the syncs cost {:.1} % of throughput)",
            s3tir_capture::session::SYNC_INTERVAL.as_secs_f64(),
            r.syncs,
            r.sync_ms_mean,
            r.sync_ms_max,
            reference.realtime_ratio,
            100.0 * sync_cost
        );
    }
    Ok(())
}

fn tempfile_dir() -> Result<PathBuf> {
    let d = std::env::temp_dir().join(format!("s3tir-bench-{}", std::process::id()));
    std::fs::create_dir_all(&d).with_context(|| format!("create {}", d.display()))?;
    Ok(d)
}
