//! `s3tir-capture`: thermal + RGB capture for s3tir rigs. This file holds the clap top level,
//! the logging set-up and the dispatch; each job is a module of [`cli`].

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

use cli::bench::BenchArgs;
use cli::export::ExportArgs;
use cli::info::InfoArgs;
use cli::inspect::InspectArgs;
use cli::list::ListArgs;
use cli::record::RecordArgs;
use cli::replay::ReplayArgs;

/// Capture radiometric thermal (Y16) and RGB video from a rig's cameras over V4L2 (or the
/// simulated rig) into a crash-safe MCAP session; inspect, replay and export sessions.
///
/// Record:  s3tir-capture --device /dev/video0 --rgb /dev/video2 --out session.mcap
///          s3tir-capture --device sim --rgb sim --out session.mcap --duration-s 10
#[derive(Debug, Parser)]
#[command(
    name = "s3tir-capture",
    version,
    about,
    long_about,
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    record: RecordArgs,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List V4L2 capture devices: path, driver, card, formats with sizes and rates, role guess.
    List(ListArgs),
    /// Summarise a session: streams, counts, duration, drops, FFC frames, sync statistics,
    /// and whether the file was truncated (recorder killed): it is read up to its last
    /// complete chunk. A file with corrupt data that is all there (bad CRC, impossible
    /// lengths: damage, not a cut) is summarised up to the damage, then exits non-zero naming
    /// the byte offset.
    Info(InfoArgs),
    /// Push every recorded frame through the live capture pipeline again (parse, drop
    /// detection, pairing); prints the frame digest, which equals `info`'s when every frame
    /// is byte-identical.
    Replay(ReplayArgs),
    /// Export a session. `--out DIR`: paired frames in the s3tir-calib board-folder layout
    /// (thermal/NNNN.png 16-bit, rgb/NNNN.png, pair k under the same name). `--dataset DIR`:
    /// a posed thermal dataset for s3tir-train (COLMAP layout, radiometric 16-bit images
    /// untouched), made by `s3tir-calib poses` (run from this program's folder: COLMAP on the
    /// RGB keyframes, thermal poses composed with the calibrated extrinsic; `--with-rgb`: the
    /// posed RGB keyframes too, for joint training); see its --help.
    Export(ExportArgs),
    /// Measure the recorder's sustained throughput on Boson 640×512 Y16 @ 60 Hz + RGB 1080p
    /// MJPEG @ 30 Hz (synthetic buffers), as a ratio to real time, and what the writer's
    /// once-a-second fdatasync costs (the same load without syncs, run first, is the reference).
    Bench(BenchArgs),
    /// Inspect thermal image files from other cameras: each file's metadata (camera, capture
    /// time, GPS from EXIF and DJI's XMP, altitudes, gimbal and flight angles) and, for FLIR
    /// `.fff` frames and radiometric JPEGs (FLIR hand-helds, DJI Zenmuse XT/XT2, Duo Pro R), the
    /// camera's Planck calibration, the conditions it stored and the temperatures under them
    /// (each condition overridable: --emissivity, --distance-m, --reflected-c, --atmosphere-c,
    /// --humidity-percent, --window-c, --window-transmission). `--out DIR`: each radiometric
    /// frame as a 16-bit PNG at 0.01 K per count, and inspect.json with every file's metadata
    /// and parameters as used.
    Inspect(InspectArgs),
}

/// Runs the command; an error is printed once, as one `error: …` line (the whole cause chain,
/// `s3tir_capture::Chain`), and exits 1.
fn main() -> std::process::ExitCode {
    s3tir_capture::error::exit_with(run())
}

fn run() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::List(a)) => cli::list::run(&a),
        Some(Command::Info(a)) => cli::info::run(&a),
        Some(Command::Replay(a)) => cli::replay::run(&a),
        Some(Command::Export(a)) => cli::export::run(&a),
        Some(Command::Bench(a)) => cli::bench::run(&a),
        Some(Command::Inspect(a)) => cli::inspect::run(&a),
        None => cli::record::run(cli.record),
    }
}

#[cfg(test)]
mod tests {
    //! Proves: the flags renamed with their unit (`--duration-s`, `--trigger-rate-hz`) still
    //! accept their old spelling, hidden, so scripts keep working.
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use clap::{CommandFactory, Parser};

    use super::Cli;

    #[test]
    fn unit_suffixed_flags_keep_their_old_spelling_hidden() {
        for args in [
            [
                "s3tir-capture",
                "--duration-s",
                "2",
                "--trigger-rate-hz",
                "30",
            ],
            ["s3tir-capture", "--duration", "2", "--trigger-rate", "30"],
        ] {
            let cli = Cli::try_parse_from(args).unwrap();
            assert_eq!(cli.record.duration_s(), Some(2.0));
            assert_eq!(cli.record.trigger_rate_hz(), Some(30.0));
        }
        let help = Cli::command().render_long_help().to_string();
        assert!(help.contains("--duration-s <DURATION_S>"), "{help}");
        assert!(
            !help.contains("--duration <"),
            "old spelling hidden: {help}"
        );
        assert!(
            !help.contains("--trigger-rate <"),
            "old spelling hidden: {help}"
        );
    }
}
