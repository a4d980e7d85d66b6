//! `s3tir-capture replay`: every recorded frame pushed through the live capture pipeline
//! again, with a spinner, optionally into a new session.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use s3tir_capture::session::SessionRecord;
use s3tir_capture::tools;

use super::progress_spinner;

/// Options of `s3tir-capture replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    file: PathBuf,
    /// Pace frames at their recorded rate.
    #[arg(long)]
    realtime: bool,
    /// Write what the pipeline produces as a new session.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

/// Runs `replay`.
pub fn run(a: &ReplayArgs) -> Result<()> {
    let (file, realtime, out, json) = (a.file.as_path(), a.realtime, a.out.as_deref(), a.json);
    let bar = progress_spinner("replayed {pos} frames");
    let r = tools::replay(file, out, realtime, None, |rec| {
        if matches!(rec, SessionRecord::Frame { .. }) {
            bar.inc(1);
        }
    });
    bar.finish_and_clear();
    let r = r?;
    if json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "replayed {} frames ({} rejected), {} pairs ({} differ from the recording), {} drops{}; frame digest {}",
            r.frames,
            r.rejected,
            r.pairs,
            r.pair_mismatches,
            r.drops,
            if r.truncated {
                ", source truncated"
            } else {
                ""
            },
            r.frame_digest
        );
    }
    if r.pair_mismatches > 0 {
        bail!(
            "replay paired {} frames differently from the recording",
            r.pair_mismatches
        );
    }
    Ok(())
}
