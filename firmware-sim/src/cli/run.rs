//! `s3tir-firmware-sim run`: the simulated rig in real time (frames on a socket, serial
//! firmware on ptys), or a walk through a scene.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use s3tir_firmware_sim::sensor::RgbProfile;
use s3tir_firmware_sim::serve::{RgbFormat, ServeConfig, serve};
use s3tir_firmware_sim::walk::{TagInk, WalkKind, WalkRig, WalkRoom, WalkSpec, serve_walk};

use super::{ProfileArg, RgbSizeArg};

/// Options of `s3tir-firmware-sim run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Thermal core.
    #[arg(long, value_enum, default_value = "lepton35")]
    pub profile: ProfileArg,
    /// Also serve the RGB camera (MJPEG at 30 Hz, --rgb-size) on the same socket.
    #[arg(long)]
    pub rgb: bool,
    /// RGB image size. 640×360 by default: the dev build keeps 30 Hz at that size on a
    /// loaded machine (see firmware-sim/README.md, `run`).
    #[arg(long, value_enum, default_value = "640x360")]
    pub rgb_size: RgbSizeArg,
    /// Unix socket path to listen on (replaced if it exists).
    #[arg(long)]
    pub socket: PathBuf,
    /// Stop after this many seconds (default: run until stopped).
    #[arg(long)]
    pub duration: Option<f64>,
    /// RGB camera in low light (2 % exposure: shot and read noise dominate).
    #[arg(long)]
    pub low_light: bool,
    /// RGB output format.
    #[arg(long, value_enum, default_value = "mjpeg")]
    pub rgb_format: RgbFormatArg,
    /// Append Lepton telemetry rows (160×122) to thermal frames.
    #[arg(long)]
    pub telemetry: bool,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Walk the rig through a textured scene instead of facing the board: `orbit` (a
    /// circle around it) or `handheld` (a person walking around it: drift, step bob, roll,
    /// tremor); or `board`: the rig still and the board waved through 1 s poses (a
    /// calibration session). Frames are rendered per pose (RGB at 10 Hz; slower than real time on a
    /// small machine, stamped on the walk's clock); --duration is the walk's length
    /// (default 20 s); no serial ptys. Prints `walk_done: thermal=N rgb=M` when every
    /// frame is sent. See firmware-sim/README.md, `run --walk`.
    #[arg(long, value_enum)]
    pub walk: Option<WalkArg>,
    /// With --walk: write the truth (cameras, extrinsic, every frame's pose) to
    /// DIR/truth.json when the walk ends.
    #[arg(long, requires = "walk")]
    pub truth_dir: Option<PathBuf>,
    /// With --walk: how the room's AprilTags are made. `printed`: paper, the RGB camera
    /// sees them; `heated`: aluminium foil over a heated black panel (310 K), which the
    /// thermal camera sees too (inverted) — fiducials for a rig without RGB.
    #[arg(long, value_enum, default_value = "printed", requires = "walk")]
    pub walk_tags: WalkTagsArg,
    /// With --walk orbit|handheld: the emissivity board (9 × 6 squares of 60 mm, warmed to
    /// 305 K) stands in the room, seen over about half a lap; its board.toml and pose go
    /// beside the truth (the poses stage's --board).
    #[arg(long, requires = "walk")]
    pub walk_board: bool,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum RgbFormatArg {
    /// Motion JPEG (V4L2 `MJPG`), quality 85.
    Mjpeg,
    /// Packed YUYV 4:2:2 (V4L2 `YUYV`).
    Yuyv,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum WalkTagsArg {
    Printed,
    Heated,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum WalkArg {
    Orbit,
    Handheld,
    /// The rig still, the emissivity board waved in front of it (a calibration session;
    /// board.toml beside the truth).
    Board,
}

/// A stop flag that SIGINT/SIGTERM set, so Ctrl-C stops the rig cleanly (socket removed).
/// Real handlers (`ctrlc`), not signals blocked in this thread and taken by a waiting one: a
/// process-directed signal goes to any thread that does not block it, and libraries start
/// threads before `main` runs (OpenBLAS, linked through OpenCV, starts its pool at load), so
/// a mask set here does not cover them and the signal killed the rig with its socket left.
fn stop_on_signals() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || {
        tracing::info!("SIGINT/SIGTERM: stopping");
        flag.store(true, Ordering::Relaxed);
    })
    .context("installing the SIGINT/SIGTERM handler")?;
    Ok(stop)
}

/// Runs the rig `a` asks for until it is stopped or its duration ends.
pub fn run(a: RunArgs) -> Result<()> {
    let RunArgs {
        profile,
        rgb,
        rgb_size,
        socket,
        duration,
        rgb_format,
        low_light,
        telemetry,
        seed,
        walk,
        truth_dir,
        walk_tags,
        walk_board,
    } = a;
    let mut thermal = profile.profile();
    if telemetry {
        thermal.telemetry_rows = 2;
    }
    let cfg = ServeConfig {
        thermal,
        rgb: rgb.then(|| {
            let full = if low_light {
                RgbProfile::hd720_low_light()
            } else {
                RgbProfile::hd720()
            };
            rgb_size.apply(full)
        }),
        rgb_format: match rgb_format {
            RgbFormatArg::Mjpeg => RgbFormat::Mjpeg,
            RgbFormatArg::Yuyv => RgbFormat::Yuyv,
        },
        socket,
        duration_s: duration,
        seed,
        stop_on_stdin_eof: true,
        stop: stop_on_signals()?,
    };
    let mut announce = |key: &str, value: &str| {
        println!("{key}: {value}");
        // The parent reads these lines as they come.
        let _ = std::io::Write::flush(&mut std::io::stdout());
    };
    if let Some(kind) = walk {
        let stop = s3tir_firmware_sim::serve::watch_stop(&cfg);
        let rig = WalkRig {
            thermal: cfg.thermal,
            rgb: cfg.rgb,
            seed,
        };
        let spec = WalkSpec {
            kind: match kind {
                WalkArg::Orbit => WalkKind::Orbit,
                WalkArg::Handheld => WalkKind::Handheld,
                WalkArg::Board => WalkKind::Board,
            },
            duration_s: cfg.duration_s.unwrap_or(20.0),
            truth_dir,
            room: WalkRoom {
                tags: match walk_tags {
                    WalkTagsArg::Printed => TagInk::Printed,
                    WalkTagsArg::Heated => TagInk::Heated,
                },
                board: walk_board,
            },
        };
        serve_walk(&cfg.socket, &rig, &spec, stop, &mut announce)
            .context("running the simulated walk")?;
        return Ok(());
    }
    serve(cfg, &mut announce).context("running the simulated rig")?;
    Ok(())
}
