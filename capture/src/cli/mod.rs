//! The jobs of `s3tir-capture`, one module each (their options and what they run); the
//! binary's `main.rs` holds the clap top level, the logging set-up and the dispatch.
//!
//! - [`record`]: recording (no subcommand): the record options, the sources (V4L2, nokhwa,
//!   the simulated rig), serial control, the summary.
//! - [`live`]: what a running recording shows and obeys: the status line, SIGINT/SIGTERM,
//!   the end of a simulated walk.
//! - [`info`]: `info`: a session's summary.
//! - [`replay`]: `replay`: a session pushed through the live pipeline again.
//! - [`export`]: `export`: board-folder pairs, and `--dataset` through `s3tir-calib poses`.
//! - [`bench`]: `bench`: the recorder's throughput and the cost of its syncs.
//! - [`list`]: `list`: the V4L2 capture devices.
//! - [`inspect`]: `inspect`: image files' metadata, and FLIR `.fff` frames and radiometric
//!   JPEGs converted to kelvin, written as 16-bit centikelvin PNGs.

pub mod bench;
pub mod export;
pub mod info;
pub mod inspect;
pub mod list;
pub mod live;
pub mod record;
pub mod replay;

/// A duration in seconds: finite and above zero (`Duration::from_secs_f64` panics otherwise).
pub fn positive_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|e| format!("{s:?} is not a number of seconds: {e}"))?;
    if v.is_finite() && v > 0.0 && v < 1e9 {
        Ok(v)
    } else {
        Err(format!("{s} s: must be a positive number of seconds"))
    }
}

/// A spinner on stderr with the elapsed time and `msg` (an indicatif template: `{pos}` is the
/// count); drawn only when stderr is a terminal, like the recorder's status line.
pub fn progress_spinner(msg: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new_spinner();
    b.set_style(
        indicatif::ProgressStyle::with_template(&format!("{{spinner}} {{elapsed}} {msg}"))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    b
}
