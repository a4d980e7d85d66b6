//! `s3tir-firmware-sim`: the simulated rig's binary. Logging and dispatch; each subcommand's
//! options and run are in `cli/` (`board`, `scene`, `run`).

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// The simulated s3tir rig: a thermal core, an RGB camera and the rig controller firmware,
/// producing physically plausible frames and ground truth when no hardware is attached.
///
/// Everything is seeded: the same command with the same seed writes the same bytes.
#[derive(Debug, Parser)]
#[command(name = "s3tir-firmware-sim", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Write a calibration set of the emissivity-coated board seen by the thermal and RGB
    /// cameras: DIR/board.toml, DIR/thermal/NNNN.png (16-bit TLinear centikelvin),
    /// DIR/rgb/NNNN.png (8-bit sRGB), DIR/truth.json (true cameras, extrinsic, board poses).
    Board(cli::board::BoardArgs),
    /// Write a small thermal scene dataset for the trainer (--layout objects: heated pipe, box
    /// with an emissivity edge, radiator panel, ground plane, seen from an orbit; --layout wall:
    /// a wall with an emissivity edge and an in-wall heating pipe; --layout facade: a brick
    /// facade with warm mortar joints, a surface-mounted pipe and a warm cabinet with foil
    /// labels, texture finer than the primitives, meant for 640×512): COLMAP text model in
    /// DIR/sparse/0/, 16-bit TLinear PNGs in DIR/images/, RGB in DIR/rgb/, ground-truth depth
    /// and temperature in DIR/depth/ and DIR/temperature/, and the visible surface with its
    /// apparent temperature in DIR/truth/surface.ply (for scoring meshes).
    ///
    /// With --rgb-scale K: the joint RGB + thermal layout instead, a thermal camera
    /// (--width × --height) and an RGB camera of K times its resolution, rigidly 3 cm apart:
    /// DIR/images/thermal/NNNN.png and DIR/images/rgb/NNNN.png (both cameras in one COLMAP
    /// model in DIR/sparse/0/), DIR/holdout.txt, and truth in DIR/truth/ (noise-free apparent
    /// temperature at the thermal and at the RGB resolution, depth of both cameras, noise-free
    /// RGB, the visible surface DIR/truth/surface.ply). See firmware-sim/README.md, `scene`.
    Scene(cli::scene::SceneArgs),
    /// Run the simulated rig in real time: frames over a Unix socket (simwire), the Boson FSLP
    /// firmware and the rig controller on pseudo-terminals. Prints `key: value` lines
    /// (`socket`, `fslp_pty`, `rig_pty`, `thermal`, `rgb`, `ready`) on stdout, then serves until
    /// SIGINT/SIGTERM, stdin EOF (only when stdin is a pipe a parent holds) or the duration ends.
    Run(cli::run::RunArgs),
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
    match Cli::parse().command {
        Command::Board(a) => cli::board::run(a),
        Command::Scene(a) => cli::scene::run(a),
        Command::Run(a) => cli::run::run(a),
    }
}
