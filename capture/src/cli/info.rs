//! `s3tir-capture info`: a session's summary (streams, counts, drops, FFC, sync, truncation),
//! and an error naming the byte offset when the file is damaged.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use s3tir_capture::tools;

/// Options of `s3tir-capture info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    file: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `info`.
pub fn run(a: &InfoArgs) -> Result<()> {
    let (file, json) = (a.file.as_path(), a.json);
    let s = tools::info(file)?;
    // Damage (corrupt data that is all in the file, unlike a crash's cut) is an error after
    // the summary of what could be read.
    let damaged = |s: &tools::SessionSummary| match &s.damage {
        Some(d) => Err(anyhow::anyhow!(
            "{} is damaged at byte {}: {} ({} chunks before it were read)",
            file.display(),
            d.offset,
            d.reason,
            s.chunks
        )),
        None => Ok(()),
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return damaged(&s);
    }
    println!("{}", s.path.display());
    if s.truncated {
        println!(
            "  TRUNCATED: read up to the last complete chunk ({})",
            s.truncation_reason.as_deref().unwrap_or("")
        );
    }
    println!(
        "  duration {:.2} s, {} chunks, device {}",
        s.duration_s, s.chunks, s.thermal_device
    );
    for (name, st) in &s.streams {
        println!(
            "  {name:8} frames {:6}  drops {:4} (recorder queue {}, source {})  ffc {:4}  rejected {}",
            st.frames, st.drops, st.queue_drops, st.source_drops, st.ffc_frames, st.rejected
        );
        println!(
            "           {:.3} Hz over {:.2} s (device stamps), delivery lag up to {:.1} ms",
            st.rate_hz, st.span_s, st.max_delivery_lag_ms
        );
    }
    println!(
        "  pairs {}  sync error mean {:.3} ms, rms {:.3} ms, max |{:.3}| ms",
        s.pairs,
        s.sync.mean_ns / 1e6,
        s.sync.rms_ns / 1e6,
        s.sync.max_abs_ns as f64 / 1e6
    );
    if let Some(m) = &s.clock {
        println!(
            "  rig controller clock: {} triggers, drift {:+.2} ppm, sync residual rms {:.1} us, max {:.1} us ({} pulses matched, {} outliers)",
            s.triggers,
            m.drift_ppm,
            m.residual_rms_ns / 1e3,
            m.residual_max_ns / 1e3,
            m.matched,
            m.outliers
        );
    }
    println!(
        "  reconnects {}  stalls {}  frame digest {}",
        s.reconnects, s.stalls, s.frame_digest
    );
    damaged(&s)
}
